// NF_MULTIVERSION: a kernel compiled for AVX-512, AVX2 and baseline x86-64;
// the loader picks one at run time (function multiversioning through an
// ifunc), so the build stays portable. The form of target_clones is chosen
// when the package is configured (cmake/NormalFusionTargetClones.cmake),
// which passes NF_TARGET_CLONES to the library's sources:
//   2  "arch=x86-64-v4", "avx2", "default"  (GCC 12 and later)
//   1  "avx512f", "avx2", "default"         (GCC before 12)
//   0  no clones: one baseline build (other compilers and architectures)
// Without NF_TARGET_CLONES (a translation unit outside the library) the
// macro is empty.
#pragma once

#if defined(__x86_64__) && defined(NF_TARGET_CLONES) && NF_TARGET_CLONES == 2
#define NF_MULTIVERSION \
  __attribute__((target_clones("arch=x86-64-v4", "avx2", "default")))
#elif defined(__x86_64__) && defined(NF_TARGET_CLONES) && NF_TARGET_CLONES == 1
#define NF_MULTIVERSION \
  __attribute__((target_clones("avx512f", "avx2", "default")))
#else
#define NF_MULTIVERSION
#endif
