// Resource URLs of file parameters, as camera_info_manager reads its
// ~camera_info_url: "package://<package>/<path>" (the package's folder from
// rospack), "file:///<absolute path>", or a plain path. ${ROS_HOME} in a
// file URL or path is ROS_HOME, else ~/.ros (camera_info_manager's rule).
//
// Thread-safe (rospack's lookup is).
#pragma once

#include <string>

namespace structured_light_stabilizer
{

// The file `url` names; false with *error when it names none (an unknown
// package, another URL scheme, an empty string).
bool resolveResourceUrl(const std::string& url, std::string* path, std::string* error);

}  // namespace structured_light_stabilizer
