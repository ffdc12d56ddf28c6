// Heavy cases inside the sanitized tiers (tests/unit, tests/cli) run in the Release build
// only: under AddressSanitizer and UndefinedBehaviorSanitizer they would take five to ten
// times as long, and the code they exercise is covered there by quicker cases. Each use
// says, in a comment beside it, which sanitized case covers its code. CMake defines
// CCDPSF_SANITIZED in the sanitizer build (tests/README.md).
#ifndef CCDPSF_TESTS_SUPPORT_SLOW_TEST_H_
#define CCDPSF_TESTS_SUPPORT_SLOW_TEST_H_

#include "gtest/gtest.h"

#ifdef CCDPSF_SANITIZED
#define CCDPSF_RELEASE_ONLY() \
  GTEST_SKIP() << "heavy case: run in the Release build only (tests/README.md)"
#else
#define CCDPSF_RELEASE_ONLY() static_cast<void>(0)
#endif

#endif  // CCDPSF_TESTS_SUPPORT_SLOW_TEST_H_
