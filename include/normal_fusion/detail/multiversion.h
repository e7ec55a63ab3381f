// NF_MULTIVERSION: a kernel compiled for AVX-512 (x86-64-v4), AVX2 and
// baseline x86-64; the loader picks one at run time (GCC function
// multiversioning), so the build stays portable.
#pragma once

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define NF_MULTIVERSION \
  __attribute__((target_clones("arch=x86-64-v4", "avx2", "default")))
#else
#define NF_MULTIVERSION
#endif
