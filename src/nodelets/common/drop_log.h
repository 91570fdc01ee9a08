// Throttling of "frame dropped" messages in the nodelets: each kind of
// problem is logged at once, then at most every period, with the number of
// frames dropped for it meanwhile. The kind is the message with its digits
// removed except inside 'quotes' (names such as '16UC1'), so that one
// problem with varying sizes ("step 100", "step 63") is one kind, while
// different problems (an encoding, an empty image, a short step, NaN
// intrinsics) are each named; a throttle per call site would show only the
// first of them, and one keyed on the last message alone floods rosout when
// bad frames of two kinds alternate.
#pragma once

#include <cctype>
#include <chrono>
#include <map>
#include <mutex>
#include <string>

namespace structured_light_stabilizer
{

class DropLog
{
public:
  explicit DropLog(double period_s = 5.0) : period_(std::chrono::duration<double>(period_s)) {}

  // True when `message` is to be logged now; *suppressed is then the number
  // of frames of its kind dropped silently since it was last logged.
  bool shouldLog(const std::string& message, int* suppressed)
  {
    std::string kind;
    kind.reserve(message.size());
    bool quoted = false;
    for (char c : message)
    {
      quoted = c == '\'' ? !quoted : quoted;
      if (quoted || !std::isdigit(static_cast<unsigned char>(c)))
        kind += c;
    }
    const auto now = std::chrono::steady_clock::now();
    std::lock_guard<std::mutex> lock(mutex_);
    // Forget kinds not seen for a while: the map stays small whatever comes.
    for (auto it = kinds_.begin(); it != kinds_.end();)
      it = now - it->second.last_logged > 10 * period_ ? kinds_.erase(it) : std::next(it);
    auto it = kinds_.find(kind);
    if (it != kinds_.end() && now - it->second.last_logged < period_)
    {
      ++it->second.suppressed;
      return false;
    }
    Entry& e = kinds_[kind];
    *suppressed = e.suppressed;
    e.suppressed = 0;
    e.last_logged = now;
    return true;
  }

private:
  struct Entry
  {
    std::chrono::steady_clock::time_point last_logged;
    int suppressed = 0;
  };
  std::chrono::duration<double> period_;
  std::mutex mutex_;
  std::map<std::string, Entry> kinds_;
};

}  // namespace structured_light_stabilizer
