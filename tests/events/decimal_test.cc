#include "evkit/events/decimal.h"

#include <gtest/gtest.h>

#include <random>
#include <string>

namespace evkit {
namespace {

int64_t parse(const std::string& s, bool* ok = nullptr) {
  const char* p = s.data();
  int64_t us = -12345;
  const bool good = parseSecondsAsMicros(p, s.data() + s.size(), us) && p == s.data() + s.size();
  if (ok) *ok = good;
  return good ? us : -12345;
}

TEST(Decimal, ParsesSecondsExactlyToMicroseconds) {
  EXPECT_EQ(parse("0"), 0);
  EXPECT_EQ(parse("0.000001"), 1);
  EXPECT_EQ(parse("1.5"), 1500000);
  EXPECT_EQ(parse("+2.25"), 2250000);
  EXPECT_EQ(parse("-0.000001"), -1);
  EXPECT_EQ(parse(".5"), 500000);
  EXPECT_EQ(parse("3."), 3000000);
  // Absolute Unix time: 16 significant digits, more than a double holds exactly.
  EXPECT_EQ(parse("1605537493.718345"), 1605537493718345);
  EXPECT_EQ(parse("1605537493.718345000"), 1605537493718345);
  EXPECT_EQ(parse("0001605537493.718345"), 1605537493718345);
}

TEST(Decimal, RoundsBeyondMicrosecondsHalfAwayFromZero) {
  EXPECT_EQ(parse("0.0000014"), 1);
  EXPECT_EQ(parse("0.0000015"), 2);
  EXPECT_EQ(parse("0.0000025"), 3);
  EXPECT_EQ(parse("-0.0000015"), -2);
  EXPECT_EQ(parse("0.0000004999"), 0);
}

TEST(Decimal, ParsesScientificNotation) {
  EXPECT_EQ(parse("1.5e-05"), 15);
  EXPECT_EQ(parse("1.605537493718345e+09"), 1605537493718345);
  EXPECT_EQ(parse("2E3"), 2000000000);
  EXPECT_EQ(parse("1e-7"), 0);
}

TEST(Decimal, RejectsMalformedAndOverflowingNumbers) {
  bool ok = true;
  for (const std::string bad :
       {"", "-", ".", "abc", "1e", "1e+", "99999999999999999999", "1e20", "--1"}) {
    parse(bad, &ok);
    EXPECT_FALSE(ok) << "'" << bad << "'";
  }
  // Stops at the first character that is not part of a number.
  const std::string s = "1.5x";
  const char* p = s.data();
  int64_t us = 0;
  ASSERT_TRUE(parseSecondsAsMicros(p, s.data() + s.size(), us));
  EXPECT_EQ(us, 1500000);
  EXPECT_EQ(*p, 'x');
}

TEST(Decimal, FormatThenParseIsIdentityOnRandomMicroseconds) {
  std::mt19937_64 rng(7);
  std::uniform_int_distribution<int64_t> dist(-(int64_t{1} << 55), int64_t{1} << 55);
  char buf[32];
  for (int i = 0; i < 100000; ++i) {
    const int64_t t =
        i < 3 ? std::array<int64_t, 3>{0, -1, 1605537493718345}[static_cast<size_t>(i)] : dist(rng);
    char* end = formatMicrosAsSeconds(t, buf);
    EXPECT_EQ(parse(std::string(buf, end)), t);
  }
  char* end = formatMicrosAsSeconds(1605537493000001, buf);
  EXPECT_EQ(std::string(buf, end), "1605537493.000001");
  end = formatMicrosAsSeconds(-1500000, buf);
  EXPECT_EQ(std::string(buf, end), "-1.500000");
}

TEST(Decimal, ParseIntChecksRange) {
  const std::string s = "65536";
  const char* p = s.data();
  int64_t v = 0;
  EXPECT_FALSE(parseInt(p, s.data() + s.size(), 0, 65535, v));
  EXPECT_TRUE(parseInt(p, s.data() + s.size(), 0, 65536, v));
  EXPECT_EQ(v, 65536);
}

}  // namespace
}  // namespace evkit
