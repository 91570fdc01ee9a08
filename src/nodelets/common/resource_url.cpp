#include "nodelets/common/resource_url.h"

#include <cstdlib>

#include <ros/package.h>

namespace structured_light_stabilizer
{

namespace
{

bool startsWith(const std::string& s, const std::string& prefix)
{
  return s.compare(0, prefix.size(), prefix) == 0;
}

// ${ROS_HOME} -> $ROS_HOME, else $HOME/.ros.
std::string expandRosHome(std::string s)
{
  const std::string key = "${ROS_HOME}";
  const size_t at = s.find(key);
  if (at == std::string::npos)
    return s;
  const char* ros_home = std::getenv("ROS_HOME");
  const char* home = std::getenv("HOME");
  const std::string value = ros_home ? ros_home : std::string(home ? home : "") + "/.ros";
  return s.replace(at, key.size(), value);
}

}  // namespace

bool resolveResourceUrl(const std::string& url, std::string* path, std::string* error)
{
  if (url.empty())
  {
    *error = "empty URL";
    return false;
  }
  if (startsWith(url, "package://"))
  {
    const std::string rest = url.substr(10);
    const size_t slash = rest.find('/');
    const std::string package = rest.substr(0, slash);
    const std::string folder = package.empty() ? std::string() : ros::package::getPath(package);
    if (folder.empty())
    {
      *error = "package '" + package + "' of '" + url + "' is not found (is the workspace sourced?)";
      return false;
    }
    *path = folder + (slash == std::string::npos ? std::string() : rest.substr(slash));
    return true;
  }
  if (startsWith(url, "file://"))
  {
    *path = expandRosHome(url.substr(7));
    if (path->empty() || (*path)[0] != '/')
    {
      *error = "'" + url + "' is not file:///<absolute path>";
      return false;
    }
    return true;
  }
  if (url.find("://") != std::string::npos)
  {
    *error = "'" + url + "' is neither package://, file:// nor a path";
    return false;
  }
  *path = expandRosHome(url);
  return true;
}

}  // namespace structured_light_stabilizer
