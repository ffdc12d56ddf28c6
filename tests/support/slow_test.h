// End-to-end cases that take a minute or more in the Release build run there only: under
// the address and undefined-behaviour sanitizers they would take ten times as long, and the
// code they exercise is covered there by the quicker tests. CMake defines CCDPSF_SANITIZED
// for the sanitizer build.
#ifndef CCDPSF_TESTS_SUPPORT_SLOW_TEST_H_
#define CCDPSF_TESTS_SUPPORT_SLOW_TEST_H_

#include "gtest/gtest.h"

#ifdef CCDPSF_SANITIZED
#define CCDPSF_RELEASE_ONLY() \
  GTEST_SKIP() << "slow end-to-end case: run in the Release build only"
#else
#define CCDPSF_RELEASE_ONLY() static_cast<void>(0)
#endif

#endif  // CCDPSF_TESTS_SUPPORT_SLOW_TEST_H_
