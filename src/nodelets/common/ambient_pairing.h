// PoseDelta nodelet, strobed operation (~strobe): pairs each frame with the
// projector-off (ambient) frames exposed just before and just after it
// (camera/image_ambient, own stamps), so that the core tracks the rock's
// texture between them (pose_delta.h, PoseDeltaInput::ambient_*).
//
// A frame (its cloud and on-frame image) is held until the ambient frame
// after it has come; one that waits longer than max_hold_s of newer frames
// is released with the ambient frame before it alone (the core then carries
// it over the gap with the rig's velocity). Ambient frames are kept for
// max_age_s. Not thread-safe: the nodelet calls it under its frame lock.
#pragma once

#include <deque>
#include <functional>

#include <sensor_msgs/Image.h>
#include <sensor_msgs/PointCloud2.h>

namespace structured_light_stabilizer
{

class AmbientPairing
{
public:
  using Release =
      std::function<void(const sensor_msgs::PointCloud2ConstPtr& cloud, const sensor_msgs::ImageConstPtr& image,
                         const sensor_msgs::ImageConstPtr& before, const sensor_msgs::ImageConstPtr& after)>;

  explicit AmbientPairing(double max_hold_s = 0.1, double max_age_s = 0.5)
    : max_hold_s_(max_hold_s), max_age_s_(max_age_s)
  {
  }

  void addAmbient(const sensor_msgs::ImageConstPtr& ambient, const Release& release)
  {
    // A stamp going backwards (a bag looping): start again.
    if (!ambient_.empty() && ambient->header.stamp < ambient_.back()->header.stamp)
      ambient_.clear();
    ambient_.push_back(ambient);
    while (ambient_.size() > 1 && (ambient->header.stamp - ambient_.front()->header.stamp).toSec() > max_age_s_)
      ambient_.pop_front();
    drain(release);
  }

  void addFrame(const sensor_msgs::PointCloud2ConstPtr& cloud, const sensor_msgs::ImageConstPtr& image,
                const Release& release)
  {
    held_.push_back({cloud, image});
    drain(release);
  }

  void clear()
  {
    ambient_.clear();
    held_.clear();
  }

private:
  struct Held
  {
    sensor_msgs::PointCloud2ConstPtr cloud;
    sensor_msgs::ImageConstPtr image;
  };

  // Releases the held frames, oldest first, that have their ambient frame
  // after them, or have waited long enough.
  void drain(const Release& release)
  {
    while (!held_.empty())
    {
      const Held h = held_.front();
      const ros::Time t = h.cloud->header.stamp;
      sensor_msgs::ImageConstPtr before, after;
      for (const sensor_msgs::ImageConstPtr& a : ambient_)
      {
        if (a->header.stamp <= t)
          before = a;
        else if (!after)
          after = a;
      }
      const bool waited = (held_.back().cloud->header.stamp - t).toSec() > max_hold_s_;
      if (!after && !waited)
        return;
      held_.pop_front();
      release(h.cloud, h.image, before, after);
    }
  }

  double max_hold_s_;
  double max_age_s_;
  std::deque<sensor_msgs::ImageConstPtr> ambient_;
  std::deque<Held> held_;
};

}  // namespace structured_light_stabilizer
