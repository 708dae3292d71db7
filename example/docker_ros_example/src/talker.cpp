#include <ros/ros.h>
#include <std_msgs/String.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, "talker");
  ros::NodeHandle nh;
  ros::Publisher pub = nh.advertise<std_msgs::String>("chatter", 10);
  ros::Rate rate(2);
  for (int count = 0; ros::ok(); ++count) {
    std_msgs::String msg;
    msg.data = "hello from docker-ros " + std::to_string(count);
    pub.publish(msg);
    ros::spinOnce();
    rate.sleep();
  }
  return 0;
}
