// depth_to_normals_node: the DepthToNormalsNodelet class run as a plain node
// (same topics, parameters and behaviour).
#include <nodelet/nodelet.h>
#include <ros/ros.h>

#include "normal_fusion/ros/depth_nodelet.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "depth_to_normals");
  normal_fusion::node::DepthToNormalsNodelet nodelet;
  const nodelet::M_string remappings = ros::names::getRemappings();
  nodelet::V_string my_argv(argv + 1, argv + argc);
  nodelet.init(ros::this_node::getName(), remappings, my_argv);
  // Callbacks only check and queue; the normals are computed on the
  // nodelet's worker thread.
  ros::MultiThreadedSpinner spinner(2);
  spinner.spin();
  return 0;
}
