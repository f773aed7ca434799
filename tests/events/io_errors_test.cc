// Bad input: each case gives one evkit::Error naming the file, the position and the problem.

#include <gtest/gtest.h>
#include <hdf5.h>

#include <random>

#include "evkit/base/error.h"
#include "evkit/events/io.h"
#include "evkit/events/random_events.h"
#include "test_util.h"

namespace evkit {
namespace {

using test::ScratchDir;
using test::writeText;

// Reads `path` fully and returns the error message ("" when it reads fine).
std::string readError(const std::string& path, std::optional<Format> format = std::nullopt) {
  try {
    readRecording(path, format);
  } catch (const Error& e) {
    const std::string msg = e.what();
    EXPECT_EQ(msg.find('\n'), std::string::npos) << "one line: " << msg;
    EXPECT_EQ(msg.rfind(path, 0), 0u) << "starts with the file name: " << msg;
    return msg;
  }
  return "";
}

void expectContains(const std::string& msg, const std::string& part) {
  EXPECT_NE(msg.find(part), std::string::npos) << "'" << msg << "' lacks '" << part << "'";
}

TEST(IoErrors, MissingEmptyAndUnknownFiles) {
  ScratchDir dir;
  expectContains(readError(dir / "nope.txt"), "no such file");
  writeText(dir / "empty.txt", "");
  expectContains(readError(dir / "empty.txt"), "empty file");
  writeText(dir / "what.xyz", "1 2 3 1\n");
  expectContains(readError(dir / "what.xyz"), "cannot tell the format");
  EXPECT_EQ(readError(dir / "what.xyz", Format::kText), "");  // --format overrides
}

TEST(IoErrors, MalformedTextLinesNameTheLineAndTheField) {
  ScratchDir dir;
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"0.1 1 2 1\n0.2 1 2\n", "line 2: expected 't x y p'; cannot read polarity"},
      {"0.1 1 2 1\nabc 1 2 1\n", "line 2: expected 't x y p'; cannot read the timestamp"},
      {"0.1 1 -2 1\n", "line 1: expected 't x y p'; cannot read y"},
      {"0.1 70000 2 1\n", "line 1: expected 't x y p'; cannot read x"},
      {"0.1 1 2 2\n", "line 1: expected 't x y p'; cannot read polarity"},
      {"0.1 1 2 1 9\n", "line 1: expected 't x y p'; cannot read end of line"},
      {"0.1 1 2 1\n0.05 1 2 1\n", "line 2: timestamp 0.050000 s goes back in time"},
      {"10 10\n0.1 1 2 1\n0.2 10 2 1\n",
       "line 3: event (x, y) = (10, 2) lies outside the 10x10 sensor"},
      {"0.1 1 2 1\n0.2 1 2",
       "line 2: expected 't x y p'; cannot read polarity"},  // truncated last line
      {"1e400 1 2 1\n", "line 1: expected 't x y p'; cannot read the timestamp"},
  };
  int i = 0;
  for (const auto& [text, part] : cases) {
    const std::string path = dir / ("bad" + std::to_string(i++) + ".txt");
    writeText(path, text);
    expectContains(readError(path), part);
  }
}

TEST(IoErrors, BinaryDataInATextFile) {
  ScratchDir dir;
  writeText(dir / "bin.txt", std::string("0.1 1 2 1\n\x01\x00\xff", 13));
  expectContains(readError(dir / "bin.txt"), "byte 11: binary data");
}

TEST(IoErrors, MislabelledFiles) {
  ScratchDir dir;
  writeText(dir / "text.h5", "0.1 1 2 1\n");
  expectContains(readError(dir / "text.h5"), "byte 0: no HDF5 signature");
  Recording rec;
  rec.events = randomEvents({});
  writeRecording(dir / "real.h5", rec);
  test::fs::copy_file(dir / "real.h5", dir / "real.txt");
  expectContains(readError(dir / "real.txt"),
                 "a hdf5 file named like a text file; rename it or pass --format hdf5");
}

TEST(IoErrors, TruncatedAndCorruptHdf5) {
  ScratchDir dir;
  RandomEventOptions o;
  o.count = 400'000;
  Recording rec;
  rec.events = randomEvents(o);
  writeRecording(dir / "good.h5", rec);
  const std::string bytes = test::readText(dir / "good.h5");
  // Truncated at several places: header, metadata, data.
  for (size_t cut : {size_t{100}, bytes.size() / 2, bytes.size() - 200}) {
    const std::string path = dir / ("cut" + std::to_string(cut) + ".h5");
    writeText(path, bytes.substr(0, cut));
    const std::string msg = readError(path);
    EXPECT_FALSE(msg.empty()) << "cut at " << cut;
  }
  // Flipped bytes inside the compressed data must not crash; an error or (rarely) a clean read.
  std::mt19937 rng(3);
  for (int k = 0; k < 20; ++k) {
    std::string corrupt = bytes;
    for (int j = 0; j < 64; ++j)
      corrupt[std::uniform_int_distribution<size_t>(4096, corrupt.size() - 1)(rng)] ^= 0x5a;
    const std::string path = dir / ("corrupt" + std::to_string(k) + ".h5");
    writeText(path, corrupt);
    readError(path);
  }
}

TEST(IoErrors, Hdf5AttributeWhoseDataspaceClaimsMoreThanItsMessage) {
  // h5py_earliest.h5 holds the root attribute sensor_resolution, two 8-byte integers, in a version
  // 1 attribute message: version, reserved, name, datatype and dataspace sizes (2 bytes each), then
  // the name, the datatype and the dataspace, each padded to 8 bytes (HDF5 file format
  // specification, section IV.A.2.m). Its dataspace (version 1: version, rank, flags, 5 reserved
  // bytes, then the dimensions) is made to claim 5000 elements, or a rank of 40.
  ScratchDir dir;
  const std::string bytes =
      test::readText(std::string(EVKIT_SOURCE_DIR) + "/tests/events/data/h5py_earliest.h5");
  const size_t message = bytes.find("sensor_resolution") - 8;
  ASSERT_EQ(bytes[message], 1);
  const auto padded = [](size_t n) { return (n + 7) / 8 * 8; };
  const auto size16 = [&](size_t at) {
    return static_cast<size_t>(static_cast<uint8_t>(bytes[at])) |
           static_cast<size_t>(static_cast<uint8_t>(bytes[at + 1])) << 8;
  };
  const size_t space = message + 8 + padded(size16(message + 2)) + padded(size16(message + 4));
  ASSERT_EQ(bytes[space + 1], 1);  // rank 1
  ASSERT_EQ(bytes[space + 8], 2);  // two elements
  std::string longer = bytes;
  longer[space + 8] = static_cast<char>(5000 & 0xff);
  longer[space + 9] = static_cast<char>(5000 >> 8);
  longer[space + 16] = longer[space + 8];  // the maximum dimension alike
  longer[space + 17] = longer[space + 9];
  writeText(dir / "longer.h5", longer);
  expectContains(readError(dir / "longer.h5"),
                 "byte " + std::to_string(message) +
                     ": an attribute of the root group: a value larger than its message");
  std::string ranked = bytes;
  ranked[space + 1] = 40;
  writeText(dir / "ranked.h5", ranked);
  expectContains(readError(dir / "ranked.h5"),
                 ": an attribute of the root group: a damaged dataspace");
}

TEST(IoErrors, Hdf5WithoutEventsOrWithBadValues) {
  ScratchDir dir;
  Recording rec;
  rec.events.setSensor(SensorSize{4, 4});
  rec.events.push_back(1, 1, 1, 1);
  writeRecording(dir / "ok.h5", rec);
  // An HDF5 file of another kind: no events group.
  {
    const std::string path = dir / "other.h5";
    const hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
    H5Fclose(f);
    expectContains(readError(path), "no dataset events/t or events/ts");
  }
}

// Writes an evkit-layout file with arbitrary (possibly invalid) columns through the raw C API.
void writeRawEvkit(const std::string& path, const std::vector<int64_t>& t,
                   const std::vector<uint16_t>& x, const std::vector<uint16_t>& y,
                   const std::vector<int8_t>& p, int width, int height) {
  const hid_t f = H5Fcreate(path.c_str(), H5F_ACC_TRUNC, H5P_DEFAULT, H5P_DEFAULT);
  const hid_t g = H5Gcreate2(f, "events", H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
  const auto put = [&](const char* name, hid_t type, const void* data, hsize_t n) {
    const hid_t space = H5Screate_simple(1, &n, nullptr);
    const hid_t ds = H5Dcreate2(g, name, type, space, H5P_DEFAULT, H5P_DEFAULT, H5P_DEFAULT);
    H5Dwrite(ds, type, H5S_ALL, H5S_ALL, H5P_DEFAULT, data);
    H5Dclose(ds);
    H5Sclose(space);
  };
  put("t", H5T_NATIVE_INT64, t.data(), t.size());
  put("x", H5T_NATIVE_UINT16, x.data(), x.size());
  put("y", H5T_NATIVE_UINT16, y.data(), y.size());
  put("p", H5T_NATIVE_INT8, p.data(), p.size());
  const hid_t scalar = H5Screate(H5S_SCALAR);
  for (const auto& [name, value] : {std::pair<const char*, int>{"sensor_width", width},
                                    {"sensor_height", height},
                                    {"evkit_layout", 1}}) {
    const hid_t a = H5Acreate2(f, name, H5T_NATIVE_INT, scalar, H5P_DEFAULT, H5P_DEFAULT);
    H5Awrite(a, H5T_NATIVE_INT, &value);
    H5Aclose(a);
  }
  H5Sclose(scalar);
  H5Gclose(g);
  H5Fclose(f);
}

TEST(IoErrors, Hdf5EventsOutsideTheSensorBackwardsInTimeOrMismatchedColumns) {
  ScratchDir dir;
  writeRawEvkit(dir / "back.h5", {5, 6, 4}, {1, 1, 1}, {1, 1, 1}, {1, -1, 1}, 10, 10);
  expectContains(readError(dir / "back.h5"),
                 "event 2: timestamp 4 us goes back in time (previous 6 us)");
  writeRawEvkit(dir / "out.h5", {5, 6, 7}, {1, 10, 1}, {1, 1, 1}, {1, -1, 1}, 10, 10);
  expectContains(readError(dir / "out.h5"),
                 "event 1: (x, y) = (10, 1) lies outside the 10x10 sensor");
  writeRawEvkit(dir / "pol.h5", {5, 6, 7}, {1, 1, 1}, {1, 1, 1}, {1, 0, 1}, 10, 10);
  expectContains(readError(dir / "pol.h5"), "event 1: polarity 0, expected +1 or -1");
  writeRawEvkit(dir / "len.h5", {5, 6, 7}, {1, 1}, {1, 1, 1}, {1, 1, 1}, 10, 10);
  expectContains(readError(dir / "len.h5"), "dataset events/x holds 2 values but events/t holds 3");
  writeRawEvkit(dir / "size.h5", {5}, {1}, {1}, {1}, 1 << 20, 10);
  expectContains(readError(dir / "size.h5"), "implausible sensor size");
}

TEST(IoErrors, RandomGarbageNeverCrashesTheReaders) {
  ScratchDir dir;
  std::mt19937 rng(11);
  for (int k = 0; k < 200; ++k) {
    std::string junk(std::uniform_int_distribution<size_t>(1, 2000)(rng), '\0');
    for (char& c : junk) c = static_cast<char>(rng());
    if (k % 2 == 0) {
      // Mostly valid-looking text with one damaged character.
      junk = "346 260\n";
      for (int i = 0; i < 50; ++i) junk += "0." + std::to_string(100000 + i) + " 1 2 1\n";
      junk[std::uniform_int_distribution<size_t>(0, junk.size() - 1)(rng)] =
          static_cast<char>(rng());
    }
    const std::string path = dir / ("junk" + std::to_string(k) + ".txt");
    writeText(path, junk);
    readError(path);  // must return (error or events), never crash
  }
}

}  // namespace
}  // namespace evkit
