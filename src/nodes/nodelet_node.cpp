// Runs one of the package's nodelets as a standalone node. Built four times,
// with SLS_NODELET_TYPE / SLS_NODE_NAME set by CMake, so that
// `rosrun structured_light_stabilizer spot_detector_node` behaves exactly
// like the nodelet loaded in a manager (same parameters, topics, services).
#include <nodelet/loader.h>
#include <ros/ros.h>

int main(int argc, char** argv)
{
  ros::init(argc, argv, SLS_NODE_NAME);
  nodelet::Loader loader;
  nodelet::M_string remappings(ros::names::getRemappings());
  nodelet::V_string my_argv(argv + 1, argv + argc);
  if (!loader.load(ros::this_node::getName(), SLS_NODELET_TYPE, remappings, my_argv))
  {
    ROS_FATAL("could not load nodelet %s", SLS_NODELET_TYPE);
    return 1;
  }
  ros::spin();
  return 0;
}
