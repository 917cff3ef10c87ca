// What a test may expect of the build it runs in. Under AddressSanitizer freed memory waits in a
// quarantine (256 MiB by default) and stays resident, and malloc is ASan's (mallinfo2 reports
// nothing), so bounds on resident memory do not hold and heap figures read 0; and its checks make
// a solve several times slower, so the time a test waits for a reply grows by kTimeoutScale.
#pragma once

namespace terrastride::test_support {

#if defined(__SANITIZE_ADDRESS__)
inline constexpr bool kAddressSanitizer = true;
#elif defined(__has_feature)
#if __has_feature(address_sanitizer)
inline constexpr bool kAddressSanitizer = true;
#else
inline constexpr bool kAddressSanitizer = false;
#endif
#else
inline constexpr bool kAddressSanitizer = false;
#endif

// Under ASan on 2 cores a failing session step ran past the Python client's 30 s reply timeout.
inline constexpr double kTimeoutScale = kAddressSanitizer ? 5.0 : 1.0;

}  // namespace terrastride::test_support
