// Whether the SSSE3 row kernels run here (spot_detector_rows_ssse3.cpp,
// pyramid_rows_ssse3.cpp): this build has them (SLS_SSSE3_ROWS: x86 with GCC
// or Clang, CMakeLists.txt) and this CPU has SSSE3. Asked once per process.
// Include it only from files built for the baseline instruction set (not
// the -mssse3 ones): the inline copy the linker keeps must run on any x86.
#pragma once

namespace structured_light_stabilizer
{

inline bool haveSsse3Kernels()
{
#if defined(SLS_SSSE3_ROWS)
  static const bool have = __builtin_cpu_supports("ssse3");
  return have;
#else
  return false;
#endif
}

}  // namespace structured_light_stabilizer
