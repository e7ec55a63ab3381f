# Which form of __attribute__((target_clones(...))) the C++ compiler accepts
# for the row kernels (include/normal_fusion/detail/multiversion.h). Sets
# NF_TARGET_CLONES:
#   2  "arch=x86-64-v4", "avx2", "default": GCC 12 and later
#   1  "avx512f", "avx2", "default": GCC before 12 (and compilers that take
#      it on function templates)
#   0  none: a plain baseline build (other compilers, non-x86-64 targets,
#      or NF_MULTIVERSION=OFF)
# Each form is compiled and linked (the resolver is only made when a clone is
# defined) with -Werror, so a form the compiler ignores with a warning does
# not count, on what the kernels use: a function and a function template in
# an anonymous namespace, the template's instances taken by address. Clang 14
# accepts target_clones on functions but not on templates, so it builds
# without clones. The "arch=" form is tried with GCC only: Clang 14 accepts it
# but its resolver tests the CPU vendor rather than the x86-64-v4 features, so
# that clone would never be chosen.
include(CheckCXXSourceCompiles)

option(NF_MULTIVERSION
  "Row kernels in AVX-512, AVX2 and baseline clones chosen at run time (x86-64)"
  ON)

function(nf_check_target_clones form result_var)
  set(CMAKE_REQUIRED_FLAGS "-Werror")
  set(CMAKE_REQUIRED_QUIET ON)
  check_cxx_source_compiles("
#if !defined(__x86_64__)
#error target_clones is used on x86-64 only
#endif
namespace {
__attribute__((target_clones(${form})))
float nfSquares(const float* a, int n) {
  float s = 0.0f;
  for (int i = 0; i < n; ++i) s += a[i] * a[i];
  return s;
}
template <bool kScaled>
__attribute__((target_clones(${form})))
void nfScale(int n, float c, float* a) {
  for (int i = 0; i < n; ++i) a[i] = kScaled ? c * a[i] : a[i];
}
}  // namespace
int main(int argc, char**) {
  float a[4] = {1.0f, 2.0f, 3.0f, 4.0f};
  auto scale = argc > 1 ? nfScale<true> : nfScale<false>;
  scale(4, 0.5f, a);
  return nfSquares(a, 4) > 0.0f ? 0 : 1;
}" ${result_var})
endfunction()

set(NF_TARGET_CLONES 0)
set(_nf_clones_form "none (one baseline build)")
if(NF_MULTIVERSION)
  if(CMAKE_CXX_COMPILER_ID STREQUAL "GNU")
    nf_check_target_clones([["arch=x86-64-v4", "avx2", "default"]]
      NF_HAVE_TARGET_CLONES_X86_64_V4)
  endif()
  if(NF_HAVE_TARGET_CLONES_X86_64_V4)
    set(NF_TARGET_CLONES 2)
    set(_nf_clones_form "arch=x86-64-v4, avx2, default")
  else()
    nf_check_target_clones([["avx512f", "avx2", "default"]]
      NF_HAVE_TARGET_CLONES_AVX512F)
    if(NF_HAVE_TARGET_CLONES_AVX512F)
      set(NF_TARGET_CLONES 1)
      set(_nf_clones_form "avx512f, avx2, default")
    endif()
  endif()
endif()
message(STATUS "normal_fusion: kernel clones (target_clones): ${_nf_clones_form}")
unset(_nf_clones_form)
