// Pairs each points cloud with the camera image of the same stamp, for the
// PoseDelta nodelet's texture part, with message_filters' ExactTime policy.
// A cloud whose image was dropped upstream goes on alone (geometry only) as
// soon as a later cloud finds its image (ExactTime's drop signal), or when
// the queue of unmatched stamps overflows (images stopped: each cloud then
// waits for the queue size, none is lost while clouds keep coming). A cloud
// never goes on without waiting for its image, even when it arrives first
// after a long silence: the reference must be locked with its image.
//
// Order: ExactTime signals a match before it drops the older, unmatched
// stamps. The signals are only collected during each add; they are then
// emitted sorted by stamp, so `emit` sees the clouds in stamp order (what
// frame_to_frame tracking needs).
//
// Each cloud that goes on alone while images are wanted is counted with its
// cause (`lone()`): images of later stamps had come (its own was lost
// upstream or in a subscriber queue), or the queue overflowed first.
//
// Not thread-safe: the nodelet calls it under its buffer mutex; `emit` runs
// inside addImage()/addCloud().
#pragma once

#include <algorithm>
#include <functional>
#include <memory>
#include <utility>
#include <vector>

#include <message_filters/sync_policies/exact_time.h>
#include <message_filters/synchronizer.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>

namespace structured_light_stabilizer
{

class CloudImageMatcher
{
public:
  using CloudPtr = sensor_msgs::PointCloud2ConstPtr;
  using ImagePtr = sensor_msgs::ImageConstPtr;
  // A cloud and its image (null: none, process the geometry alone).
  using Emit = std::function<void(const CloudPtr&, const ImagePtr&)>;

  CloudImageMatcher() { reset(); }

  // Unmatched stamps kept (clouds waiting for their image, images for their
  // cloud); at least 2. Forgets what is queued.
  void setImageQueueSize(int size)
  {
    queue_size_ = std::max(2, size);
    reset();
  }

  // Clouds that went on without their image, by cause, since the start.
  struct Lone
  {
    int later_images = 0;                         // an image of a later stamp had come: its own was lost
    int queue_full = 0;                           // the queue of unmatched stamps overflowed first
    int matched = 0;                              // clouds that went on with their image
    double last_stamp = 0.0, newest_image = 0.0;  // the last such cloud's stamp, the newest image's then
  };
  const Lone& lone() const { return lone_; }

  void addImage(const ImagePtr& image, const Emit& emit)
  {
    newest_image_ = std::max(newest_image_, image->header.stamp);
    sync_->add<1>(image);
    flush(emit);
  }

  // `with_images`: false while no images come by design (texture off or not
  // subscribed): the cloud goes on alone at once.
  void addCloud(const CloudPtr& cloud, bool with_images, const Emit& emit)
  {
    if (!with_images)
    {
      emit(cloud, nullptr);
      return;
    }
    sync_->add<0>(cloud);
    flush(emit);
  }

  // Images stop (texture off, unsubscribed): forget the queue; the clouds
  // still in it (at most the queue size) get no pose.
  void clearImages() { reset(); }

private:
  using Policy = message_filters::sync_policies::ExactTime<sensor_msgs::PointCloud2, sensor_msgs::Image>;

  void reset()
  {
    ready_.clear();
    newest_image_ = ros::Time();
    sync_.reset(new message_filters::Synchronizer<Policy>(Policy(queue_size_)));
    sync_->registerCallback(&CloudImageMatcher::collect, this);
    sync_->getPolicy()->registerDropCallback(&CloudImageMatcher::collect, this);
  }

  // Matched pairs and dropped tuples alike; an image without its cloud is
  // of no use.
  void collect(const CloudPtr& cloud, const ImagePtr& image)
  {
    if (!cloud)
      return;
    ready_.emplace_back(cloud, image);
    if (image)
    {
      ++lone_.matched;
      return;
    }
    ++(newest_image_ > cloud->header.stamp ? lone_.later_images : lone_.queue_full);
    lone_.last_stamp = cloud->header.stamp.toSec();
    lone_.newest_image = newest_image_.toSec();
  }

  void flush(const Emit& emit)
  {
    std::stable_sort(ready_.begin(), ready_.end(),
                     [](const Pair& a, const Pair& b) { return a.first->header.stamp < b.first->header.stamp; });
    std::vector<Pair> ready;
    ready.swap(ready_);
    for (const Pair& p : ready)
      emit(p.first, p.second);
  }

  using Pair = std::pair<CloudPtr, ImagePtr>;
  int queue_size_ = 5;
  std::unique_ptr<message_filters::Synchronizer<Policy>> sync_;
  std::vector<Pair> ready_;
  ros::Time newest_image_;
  Lone lone_;
};

}  // namespace structured_light_stabilizer
