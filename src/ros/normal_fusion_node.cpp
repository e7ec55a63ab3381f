// normal_fusion_node: the NormalFusionNodelet class run as a plain node (same
// topics, parameters and behaviour; the callbacks run on the global queue).
#include <nodelet/nodelet.h>
#include <ros/ros.h>

#include "normal_fusion/ros/nodelet.h"

int main(int argc, char** argv) {
  ros::init(argc, argv, "normal_fusion");
  normal_fusion::node::NormalFusionNodelet nodelet;
  const nodelet::M_string remappings = ros::names::getRemappings();
  nodelet::V_string my_argv(argv + 1, argv + argc);
  nodelet.init(ros::this_node::getName(), remappings, my_argv);
  // Callbacks are short (checks and queueing); the solve runs on the
  // nodelet's worker thread.
  ros::MultiThreadedSpinner spinner(2);
  spinner.spin();
  return 0;
}
