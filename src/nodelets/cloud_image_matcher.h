// Pairs each points cloud with the camera image of the same stamp, for the
// PoseDelta nodelet's texture part. Images wait in a short buffer; a cloud
// whose image has not come yet waits too (at most 3 clouds, 0.5 s of stamps);
// a cloud whose image was dropped upstream, or that waited too long, goes on
// alone (geometry only). Per-topic delivery is in order, so an image newer
// than a waiting cloud means that cloud's image will never come.
//
// Not thread-safe: the nodelet calls it under its buffer mutex, and `emit`
// runs inside the calls, in stamp order.
#pragma once

#include <deque>
#include <functional>

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

  void setImageQueueSize(int size) { image_queue_size_ = size; }

  void addImage(const ImagePtr& image, const Emit& emit)
  {
    images_.push_back(image);
    while (static_cast<int>(images_.size()) > image_queue_size_)
      images_.pop_front();
    // Clouds waiting for this image, or for an image that will never come.
    while (!pending_.empty())
    {
      const CloudPtr cloud = pending_.front();
      if (cloud->header.stamp > image->header.stamp)
        break;
      pending_.pop_front();
      emit(cloud, cloud->header.stamp == image->header.stamp ? image : nullptr);
    }
  }

  // `with_images`: false while no images come by design (texture off or not
  // subscribed): the cloud goes on alone at once.
  void addCloud(const CloudPtr& cloud, bool with_images, const Emit& emit)
  {
    // Images stopped (or never came): do not hold clouds back for long.
    while (!pending_.empty() && (cloud->header.stamp - pending_.front()->header.stamp).toSec() > 0.5)
    {
      emit(pending_.front(), nullptr);
      pending_.pop_front();
    }
    if (!with_images)
    {
      emit(cloud, nullptr);
      return;
    }
    for (auto it = images_.rbegin(); it != images_.rend(); ++it)
    {
      if ((*it)->header.stamp == cloud->header.stamp)
      {
        emit(cloud, *it);
        return;
      }
    }
    if (!images_.empty() && images_.back()->header.stamp > cloud->header.stamp)
    {
      emit(cloud, nullptr);  // its image was dropped upstream
      return;
    }
    pending_.push_back(cloud);
    while (pending_.size() > 3)
    {
      emit(pending_.front(), nullptr);
      pending_.pop_front();
    }
  }

  void clearImages() { images_.clear(); }

private:
  int image_queue_size_ = 5;
  std::deque<ImagePtr> images_;
  std::deque<CloudPtr> pending_;
};

}  // namespace structured_light_stabilizer
