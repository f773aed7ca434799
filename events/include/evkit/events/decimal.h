// Exact decimal parsing for the text formats: seconds with a fractional part to integer
// microseconds without going through a double (a double holds ~15.9 digits, a Unix time in µs has
// 16), and small unsigned integers.
#pragma once

#include <cstdint>

namespace evkit {

// Parses "[+-]digits[.digits][(e|E)[+-]digits]" seconds at [p, end) and writes the value in µs,
// rounded half away from zero. Advances p past the number. Returns false on a malformed number or
// one outside ±9.2e12 s.
bool parseSecondsAsMicros(const char*& p, const char* end, int64_t& micros);

// Parses an optionally signed decimal integer in [min, max]; advances p. False if malformed or out
// of range.
bool parseInt(const char*& p, const char* end, int64_t min, int64_t max, int64_t& value);

// Writes t (µs) as seconds with exactly six decimals ("-0.000001", "1605537493.718345"); returns
// the end of the written text. `out` needs 24 bytes.
char* formatMicrosAsSeconds(int64_t micros, char* out);

}  // namespace evkit
