/* tests/fp_bits.h - finiteness by the bits, for test code that must hold under -ffast-math too
   (make test builds the traversal and robust suites with it; isfinite() may then fold to 1). */
#ifndef FP_BITS_H
#define FP_BITS_H

#include <stdint.h>
#include <string.h>

static inline int fp_finite(double x) {
    uint64_t u;
    memcpy(&u, &x, sizeof u);
    return (u & 0x7ff0000000000000ull) != 0x7ff0000000000000ull;
}

#endif
