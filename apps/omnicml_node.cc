// omnicml_node: the engine on a running robot under ROS 1 (src/ros/ros_node.h for topics,
// frames, parameters and services; README "On a robot"). Exit codes: 0 after a clean
// shutdown (SIGINT/SIGTERM), 2 on a bad parameter, map or configuration.
#include <iostream>

#include "omnicml/common/common.h"
#include "omnicml/common/file_io.h"
#include "omnicml/ros/ros_node.h"

int main(int argc, char** argv) {
  try {
    omnicml::RosNode::InitRos(argc, argv, "omnicml_node");
    omnicml::RosNode node;
    node.Spin();
  } catch (const omnicml::Error& e) {
    std::cerr << "omnicml_node: error: " << omnicml::Excerpt(e.what(), 1000) << "\n";
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "omnicml_node: internal error: " << e.what() << "\n";
    return 1;
  }
  return 0;
}
