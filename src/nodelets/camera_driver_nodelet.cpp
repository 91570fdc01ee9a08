// CameraDriver nodelet: placeholder until its stage issue lands.
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>

namespace structured_light_stabilizer
{

class CameraDriverNodelet : public nodelet::Nodelet
{
private:
  void onInit() override
  {
    NODELET_WARN("CameraDriver: not implemented yet; this nodelet only loads");
  }
};

}  // namespace structured_light_stabilizer

PLUGINLIB_EXPORT_CLASS(structured_light_stabilizer::CameraDriverNodelet, nodelet::Nodelet)
