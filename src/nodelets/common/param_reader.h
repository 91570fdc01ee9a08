// Typed readers of a nodelet's private parameters. roscpp's param() keeps
// the default without a word when a parameter has the wrong type
// (_rock_distance:=far); these refuse it with an error that names the
// parameter, the type expected and the value given, and keep the default.
// An unset parameter keeps the default quietly.
//
// Errors go to the nodelet's own logger through `error` (a lambda around
// NODELET_ERROR that adds the nodelet's label), e.g.
//   "~rock_distance must be a number, got 'far'; keeping the default 1.5".
#pragma once

#include <cstdio>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <ros/ros.h>

namespace structured_light_stabilizer
{

class ParamReader
{
public:
  using ErrorSink = std::function<void(const std::string&)>;

  ParamReader(const ros::NodeHandle& pnh, ErrorSink error) : pnh_(pnh), error_(std::move(error)) {}

  // A number (an integer is taken as one).
  void number(const std::string& name, double* v) const
  {
    XmlRpc::XmlRpcValue value;
    if (!pnh_.getParam(name, value))
      return;
    if (value.getType() == XmlRpc::XmlRpcValue::TypeDouble)
      *v = static_cast<double>(value);
    else if (value.getType() == XmlRpc::XmlRpcValue::TypeInt)
      *v = static_cast<int>(value);
    else
      refuse(name, "a number", value, format("%g", *v));
  }

  void boolean(const std::string& name, bool* v) const
  {
    XmlRpc::XmlRpcValue value;
    if (!pnh_.getParam(name, value))
      return;
    if (value.getType() == XmlRpc::XmlRpcValue::TypeBoolean)
      *v = static_cast<bool>(value);
    else
      refuse(name, "true or false", value, *v ? "true" : "false");
  }

  // A non-negative integer (counts, sizes, seeds).
  template <typename Int>
  void integer(const std::string& name, Int* v) const
  {
    XmlRpc::XmlRpcValue value;
    if (!pnh_.getParam(name, value))
      return;
    if (value.getType() == XmlRpc::XmlRpcValue::TypeInt && static_cast<int>(value) >= 0)
      *v = static_cast<Int>(static_cast<int>(value));
    else
      refuse(name, "a non-negative integer", value, format("%lld", static_cast<long long>(*v)));
  }

  // A list of exactly n numbers. False (after an error) when set but not
  // that; true otherwise, *v untouched when unset.
  bool numbers(const std::string& name, size_t n, std::vector<double>* v) const
  {
    if (!pnh_.hasParam(name))
      return true;
    std::vector<double> value;
    if (!pnh_.getParam(name, value) || value.size() != n)
    {
      error_("~" + name + " must be a list of " + std::to_string(n) + " numbers; keeping the default");
      return false;
    }
    *v = value;
    return true;
  }

  void vector3(const std::string& name, Eigen::Vector3d* v) const
  {
    std::vector<double> value(v->data(), v->data() + 3);
    if (numbers(name, 3, &value))
      *v = Eigen::Vector3d(value[0], value[1], value[2]);
  }

private:
  template <typename T>
  static std::string format(const char* fmt, T value)
  {
    char text[64];
    std::snprintf(text, sizeof(text), fmt, value);
    return text;
  }

  void refuse(const std::string& name, const char* expected, XmlRpc::XmlRpcValue& given, const std::string& kept) const
  {
    error_("~" + name + " must be " + expected + ", got '" + given.toXml() + "'; keeping the default " + kept);
  }

  ros::NodeHandle pnh_;
  ErrorSink error_;
};

}  // namespace structured_light_stabilizer
