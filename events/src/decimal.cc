#include "evkit/events/decimal.h"

#include <charconv>
#include <cstring>

namespace evkit {

namespace {
constexpr int kMaxDigits = 19;  // a uint64 holds any 19-digit decimal
constexpr uint64_t kPow10[] = {1ULL,
                               10ULL,
                               100ULL,
                               1000ULL,
                               10000ULL,
                               100000ULL,
                               1000000ULL,
                               10000000ULL,
                               100000000ULL,
                               1000000000ULL,
                               10000000000ULL,
                               100000000000ULL,
                               1000000000000ULL,
                               10000000000000ULL,
                               100000000000000ULL,
                               1000000000000000ULL,
                               10000000000000000ULL,
                               100000000000000000ULL,
                               1000000000000000000ULL};
constexpr int kMaxPow = 18;

inline bool isDigit(char c) { return static_cast<unsigned char>(c - '0') < 10; }
}  // namespace

bool parseSecondsAsMicros(const char*& p, const char* end, int64_t& micros) {
  const char* s = p;
  bool negative = false;
  if (s < end && (*s == '-' || *s == '+')) negative = (*s++ == '-');
  // value = mantissa * 10^exp10 seconds; digits beyond kMaxDigits only shift the exponent (integer
  // part) or are dropped (fraction), which cannot change a result rounded to µs.
  uint64_t mantissa = 0;
  int digits = 0;
  int exp10 = 0;
  bool any = false;
  bool round_up = false;  // first dropped fractional digit >= 5
  while (s < end && isDigit(*s)) {
    any = true;
    if (digits < kMaxDigits) {
      mantissa = mantissa * 10 + static_cast<uint64_t>(*s - '0');
      if (mantissa) ++digits;
    } else {
      ++exp10;
    }
    ++s;
  }
  if (s < end && *s == '.') {
    ++s;
    bool dropped_first = true;
    while (s < end && isDigit(*s)) {
      any = true;
      if (digits < kMaxDigits) {
        mantissa = mantissa * 10 + static_cast<uint64_t>(*s - '0');
        if (mantissa) ++digits;
        --exp10;
      } else if (dropped_first) {
        round_up = *s >= '5';
        dropped_first = false;
      }
      ++s;
    }
  }
  if (!any) return false;
  if (s < end && (*s == 'e' || *s == 'E')) {
    ++s;
    int64_t e = 0;
    if (!parseInt(s, end, -400, 400, e)) return false;
    exp10 += static_cast<int>(e);
  }
  if (round_up) ++mantissa;  // only reached with 19 digits kept: far below µs resolution or clamped
  // µs = mantissa * 10^(exp10 + 6)
  const int shift = exp10 + 6;
  uint64_t value;
  if (mantissa == 0) {
    value = 0;
  } else if (shift >= 0) {
    if (shift > kMaxPow) return false;
    if (mantissa > static_cast<uint64_t>(INT64_MAX) / kPow10[shift]) return false;
    value = mantissa * kPow10[shift];
  } else {
    const int down = -shift;
    if (down > kMaxPow + 1) {
      value = 0;
    } else if (down == kMaxPow + 1) {
      // 10^19 does not fit: mantissa < 10^19 so the quotient is 0 or (rounded) 1.
      value = mantissa >= 5000000000000000000ULL ? 1 : 0;
    } else {
      const uint64_t div = kPow10[down];
      value = mantissa / div;
      if (mantissa % div >= div / 2 + (div & 1)) ++value;
    }
  }
  if (value > static_cast<uint64_t>(INT64_MAX)) return false;
  micros = negative ? -static_cast<int64_t>(value) : static_cast<int64_t>(value);
  p = s;
  return true;
}

bool parseInt(const char*& p, const char* end, int64_t min, int64_t max, int64_t& value) {
  const char* s = p;
  if (s < end && *s == '+') ++s;
  int64_t v = 0;
  const auto [ptr, ec] = std::from_chars(s, end, v);
  if (ec != std::errc() || v < min || v > max) return false;
  value = v;
  p = ptr;
  return true;
}

char* formatMicrosAsSeconds(int64_t micros, char* out) {
  uint64_t magnitude;
  if (micros < 0) {
    *out++ = '-';
    magnitude = static_cast<uint64_t>(-(micros + 1)) + 1;  // safe for INT64_MIN
  } else {
    magnitude = static_cast<uint64_t>(micros);
  }
  out = std::to_chars(out, out + 20, magnitude / 1000000).ptr;
  *out++ = '.';
  uint64_t frac = magnitude % 1000000;
  for (int i = 5; i >= 0; --i) {
    out[i] = static_cast<char>('0' + frac % 10);
    frac /= 10;
  }
  return out + 6;
}

}  // namespace evkit
