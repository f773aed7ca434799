#include "hdf5_filters.h"

#include <blosc.h>
#include <bzlib.h>
#include <lz4.h>
#include <zlib.h>

#include <algorithm>
#include <cstring>
#include <optional>

#include "evkit/base/error.h"
#include "hdf5_precheck.h"
#include "hdf5_util.h"

namespace evkit::detail {
namespace {

using Bytes = std::vector<uint8_t>;

struct Filter {
  H5Z_filter_t id = 0;
  std::vector<unsigned> values;  // the filter's client data (cd_values)
};

constexpr H5Z_filter_t kLzfFilter = 32000;  // h5py's LZF
constexpr H5Z_filter_t kLz4Filter = 32004;  // the HDF Group's LZ4 plugin (hdf5plugin.LZ4)
constexpr H5Z_filter_t kBzip2Filter = 307;  // the HDF Group's bzip2 plugin (hdf5plugin.BZip2)

std::string filterName(H5Z_filter_t id) {
  switch (id) {
    case H5Z_FILTER_DEFLATE:
      return "deflate";
    case H5Z_FILTER_SHUFFLE:
      return "shuffle";
    case H5Z_FILTER_FLETCHER32:
      return "fletcher32";
    case H5Z_FILTER_SZIP:
      return "szip";
    case H5Z_FILTER_NBIT:
      return "nbit";
    case H5Z_FILTER_SCALEOFFSET:
      return "scaleoffset";
    case kBzip2Filter:
      return "bzip2";
    case kLzfFilter:
      return "lzf";
    case kBloscFilter:
      return "blosc";
    case kLz4Filter:
      return "lz4";
    case 32008:
      return "bitshuffle";
    case 32015:
      return "zstd";
    default:
      return "filter " + std::to_string(id);
  }
}

bool decodedHere(H5Z_filter_t id) {
  return id == H5Z_FILTER_DEFLATE || id == H5Z_FILTER_SHUFFLE || id == H5Z_FILTER_FLETCHER32 ||
         id == static_cast<H5Z_filter_t>(kBloscFilter) || id == kLzfFilter || id == kLz4Filter ||
         id == kBzip2Filter;
}

std::vector<Filter> pipelineOf(hid_t dcpl) {
  const int n = H5Pget_nfilters(dcpl);
  std::vector<Filter> filters;
  for (int i = 0; i < n; ++i) {
    Filter f;
    unsigned flags = 0, config = 0;
    size_t count = 64;
    f.values.resize(count);
    f.id = H5Pget_filter2(dcpl, static_cast<unsigned>(i), &flags, &count, f.values.data(), 0,
                          nullptr, &config);
    f.values.resize(std::min<size_t>(count, 64));
    filters.push_back(std::move(f));
  }
  return filters;
}

// Fletcher's checksum over 16-bit big-endian words (an odd last byte is the high byte of a
// word), the sums reduced modulo 65535: HDF5 File Format Specification 3.0, "Fletcher32", which
// appends it to the chunk in little-endian order.
uint32_t fletcher32(const uint8_t* data, size_t size) {
  uint32_t a = 0, b = 0;
  size_t i = 0;
  while (i + 1 < size) {
    const size_t end = std::min(size & ~size_t{1}, i + 720);  // 360 words keep the sums in 32 bits
    for (; i < end; i += 2) {
      a += (uint32_t{data[i]} << 8) | data[i + 1];
      b += a;
    }
    a = (a & 0xffff) + (a >> 16);
    b = (b & 0xffff) + (b >> 16);
  }
  if (size % 2) {
    a += uint32_t{data[size - 1]} << 8;
    b += a;
    a = (a & 0xffff) + (a >> 16);
    b = (b & 0xffff) + (b >> 16);
  }
  a = (a & 0xffff) + (a >> 16);
  b = (b & 0xffff) + (b >> 16);
  return (b << 16) | a;
}

// Undoes a chunk's filters, checking each stage's size; `fail` throws with the chunk named.
class ChunkDecoder {
 public:
  ChunkDecoder(std::vector<Filter> filters, size_t chunk_bytes, size_t element_bytes)
      : filters_(std::move(filters)), chunk_bytes_(chunk_bytes), element_bytes_(element_bytes) {}

  // Decodes `data` in place; `skipped` is the chunk's filter mask (bit i: filter i not applied).
  template <typename Fail>
  void decode(Bytes& data, unsigned skipped, const Fail& fail) {
    // Each stage's input size when the chunk was written: known up to the first compressor.
    std::vector<std::optional<size_t>> size_before(filters_.size());
    std::optional<size_t> size = chunk_bytes_;
    const auto applied = [&](size_t i) { return i >= 32 || !(skipped >> i & 1u); };
    for (size_t i = 0; i < filters_.size(); ++i) {
      size_before[i] = size;
      if (!applied(i)) continue;
      const H5Z_filter_t id = filters_[i].id;
      if (id == H5Z_FILTER_FLETCHER32 && size) {
        *size += 4;
      } else if (id != H5Z_FILTER_SHUFFLE) {
        size.reset();
      }
    }
    for (size_t i = filters_.size(); i-- > 0;) {
      if (!applied(i)) continue;
      const Filter& f = filters_[i];
      switch (f.id) {
        case H5Z_FILTER_DEFLATE:
          inflateStage(data, size_before[i], fail);
          break;
        case H5Z_FILTER_SHUFFLE:
          unshuffle(data, f.values.empty() || f.values[0] == 0 ? element_bytes_ : f.values[0]);
          break;
        case H5Z_FILTER_FLETCHER32:
          checkFletcher32(data, fail);
          break;
        case kLzfFilter:
          unlzf(data, size_before[i], fail);
          break;
        case kLz4Filter:
          unlz4(data, size_before[i], fail);
          break;
        case kBzip2Filter:
          unbzip2(data, size_before[i], fail);
          break;
        default:  // Blosc: readHyperslab lets no other filter through
          unblosc(data, size_before[i], fail);
          break;
      }
    }
    if (data.size() != chunk_bytes_) {
      fail("its filters undone give " + std::to_string(data.size()) + " bytes, for " +
           std::to_string(chunk_bytes_));
    }
  }

 private:
  template <typename Fail>
  void inflateStage(Bytes& data, std::optional<size_t> expected, const Fail& fail) {
    z_stream z{};
    if (inflateInit(&z) != Z_OK) fail("zlib could not start");
    out_.resize(expected ? *expected : std::max<size_t>(data.size() * 4, 64));
    z.next_in = data.data();
    z.avail_in = static_cast<uInt>(data.size());
    int status = Z_OK;
    while (status == Z_OK) {
      if (z.total_out == out_.size()) {
        if (expected || out_.size() >= kMaxHdf5ChunkBytes) break;  // more than the stage holds
        out_.resize(std::min<size_t>(out_.size() * 2, kMaxHdf5ChunkBytes));
      }
      z.next_out = out_.data() + z.total_out;
      z.avail_out = static_cast<uInt>(out_.size() - z.total_out);
      status = inflate(&z, Z_SYNC_FLUSH);
      if (status == Z_OK && z.avail_in == 0 && z.avail_out != 0) break;  // the input ran out
    }
    const size_t produced = z.total_out;
    inflateEnd(&z);
    if (status != Z_STREAM_END) {
      fail("its deflate stream " +
           std::string(status == Z_OK || status == Z_BUF_ERROR ? "does not end where it should"
                                                               : "is damaged") +
           (expected ? " (" + std::to_string(*expected) + " bytes expected)" : ""));
    }
    if (expected && produced != *expected) {
      fail("its deflate stream decodes to " + std::to_string(produced) + " bytes, for " +
           std::to_string(*expected));
    }
    out_.resize(produced);
    data.swap(out_);
  }

  // Byte b of element e was stored at plane b, position e; bytes that fill no element stay.
  void unshuffle(Bytes& data, size_t width) {
    if (width <= 1 || data.size() < width) return;
    const size_t count = data.size() / width;
    out_.resize(data.size());
    const uint8_t* in = data.data();
    uint8_t* out = out_.data();
    switch (width) {  // the widths of event columns, unrolled
      case 2:
        gather<2>(in, count, out);
        break;
      case 4:
        gather<4>(in, count, out);
        break;
      case 8:
        gather<8>(in, count, out);
        break;
      default:
        for (size_t e = 0; e < count; ++e) {
          for (size_t b = 0; b < width; ++b) out[e * width + b] = in[b * count + e];
        }
    }
    std::memcpy(out + count * width, in + count * width, data.size() - count * width);
    data.swap(out_);
  }

  template <size_t kWidth>
  static void gather(const uint8_t* in, size_t count, uint8_t* out) {
    for (size_t e = 0; e < count; ++e) {
      for (size_t b = 0; b < kWidth; ++b) out[e * kWidth + b] = in[b * count + e];
    }
  }

  template <typename Fail>
  void checkFletcher32(Bytes& data, const Fail& fail) {
    if (data.size() < 4) fail("it is too short for its Fletcher32 checksum");
    const size_t n = data.size() - 4;
    const uint32_t stored = uint32_t{data[n]} | uint32_t{data[n + 1]} << 8 |
                            uint32_t{data[n + 2]} << 16 | uint32_t{data[n + 3]} << 24;
    const uint32_t computed = fletcher32(data.data(), n);
    if (stored != computed) {
      fail("its Fletcher32 checksum is " + std::to_string(stored) + ", its bytes give " +
           std::to_string(computed));
    }
    data.resize(n);
  }

  template <typename Fail>
  void unblosc(Bytes& data, std::optional<size_t> expected, const Fail& fail) {
    size_t nbytes = 0;
    if (blosc_cbuffer_validate(data.data(), data.size(), &nbytes) < 0) {
      fail("its " + std::to_string(data.size()) + " bytes are not a whole Blosc buffer");
    }
    if ((expected && nbytes != *expected) || nbytes > kMaxHdf5ChunkBytes) {
      fail(
          "its Blosc buffer holds " + std::to_string(nbytes) + " bytes, for " +
          (expected ? std::to_string(*expected) : "at most " + std::to_string(kMaxHdf5ChunkBytes)));
    }
    out_.resize(nbytes);
    if (nbytes > 0 &&
        blosc_decompress_ctx(data.data(), out_.data(), nbytes, 1) != static_cast<int>(nbytes)) {
      fail("its Blosc buffer is damaged");
    }
    data.swap(out_);
  }

  // LZF (liblzf's format, as h5py writes it): a control byte below 32 starts a run of that many
  // plus one literal bytes; above, its top 3 bits are a copy's length minus 2 (7: plus the next
  // byte) and its low 5 bits, with the byte after the length, the copy's distance back minus 1.
  template <typename Fail>
  void unlzf(Bytes& data, std::optional<size_t> expected, const Fail& fail) {
    const size_t limit = expected ? *expected : kMaxHdf5ChunkBytes;
    out_.clear();
    out_.reserve(std::min(limit, data.size() * 8));
    size_t i = 0;
    const auto damaged = [&](const std::string& what) {
      fail("its LZF stream " + what + " at byte " + std::to_string(i) + " of " +
           std::to_string(data.size()));
    };
    while (i < data.size()) {
      const unsigned control = data[i++];
      if (control < 32) {
        const size_t run = control + 1;
        if (run > data.size() - i) damaged("ends inside a literal run");
        if (run > limit - out_.size()) damaged("decodes past " + std::to_string(limit) + " bytes");
        out_.insert(out_.end(), data.begin() + static_cast<ptrdiff_t>(i),
                    data.begin() + static_cast<ptrdiff_t>(i + run));
        i += run;
        continue;
      }
      size_t length = control >> 5;
      if (length == 7) {
        if (i >= data.size()) damaged("ends inside a copy");
        length += data[i++];
      }
      length += 2;
      if (i >= data.size()) damaged("ends inside a copy");
      const size_t back = ((size_t{control} & 0x1f) << 8 | data[i++]) + 1;
      if (back > out_.size()) damaged("copies from before its start");
      if (length > limit - out_.size()) damaged("decodes past " + std::to_string(limit) + " bytes");
      for (size_t k = 0; k < length; ++k) out_.push_back(out_[out_.size() - back]);
    }
    if (expected && out_.size() != *expected) {
      fail("its LZF stream decodes to " + std::to_string(out_.size()) + " bytes, for " +
           std::to_string(*expected));
    }
    data.swap(out_);
  }

  // The LZ4 plugin's framing: the decoded size (8 bytes, big-endian) and the block size (4), then
  // each block's stored size (4) and its bytes: LZ4 where they are fewer than the block's, else
  // the block as it is.
  template <typename Fail>
  void unlz4(Bytes& data, std::optional<size_t> expected, const Fail& fail) {
    const auto big = [&](size_t at, int bytes) {
      uint64_t v = 0;
      for (int b = 0; b < bytes; ++b) v = v << 8 | data[at + static_cast<size_t>(b)];
      return v;
    };
    if (data.size() < 12) fail("its LZ4 header is cut short");
    const uint64_t total = big(0, 8), block = big(8, 4);
    if ((expected && total != *expected) || total > kMaxHdf5ChunkBytes) {
      fail(
          "its LZ4 header states " + std::to_string(total) + " bytes, for " +
          (expected ? std::to_string(*expected) : "at most " + std::to_string(kMaxHdf5ChunkBytes)));
    }
    if (block == 0 && total > 0) fail("its LZ4 header states blocks of 0 bytes");
    out_.resize(total);
    size_t at = 12;
    for (size_t done = 0; done < total;) {
      const size_t want = std::min<size_t>(block, total - done);
      if (data.size() - at < 4) fail("its LZ4 blocks end at byte " + std::to_string(at));
      const size_t stored = big(at, 4);
      at += 4;
      if (stored > data.size() - at) {
        fail("its LZ4 block at byte " + std::to_string(at - 4) + " states " +
             std::to_string(stored) + " bytes, past the chunk's end");
      }
      if (stored == want) {
        std::memcpy(out_.data() + done, data.data() + at, want);
      } else if (LZ4_decompress_safe(reinterpret_cast<const char*>(data.data() + at),
                                     reinterpret_cast<char*>(out_.data() + done),
                                     static_cast<int>(stored),
                                     static_cast<int>(want)) != static_cast<int>(want)) {
        fail("its LZ4 block at byte " + std::to_string(at - 4) + " does not decode to " +
             std::to_string(want) + " bytes");
      }
      at += stored;
      done += want;
    }
    data.swap(out_);
  }

  template <typename Fail>
  void unbzip2(Bytes& data, std::optional<size_t> expected, const Fail& fail) {
    bz_stream z{};
    if (BZ2_bzDecompressInit(&z, 0, 0) != BZ_OK) fail("bzip2 could not start");
    out_.resize(expected ? *expected : std::max<size_t>(data.size() * 4, 64));
    z.next_in = reinterpret_cast<char*>(data.data());
    z.avail_in = static_cast<unsigned>(data.size());
    size_t produced = 0;
    int status = BZ_OK;
    while (status == BZ_OK) {
      if (produced == out_.size()) {
        if (expected || out_.size() >= kMaxHdf5ChunkBytes) break;  // more than the stage holds
        out_.resize(std::min<size_t>(out_.size() * 2, kMaxHdf5ChunkBytes));
      }
      z.next_out = reinterpret_cast<char*>(out_.data() + produced);
      z.avail_out = static_cast<unsigned>(out_.size() - produced);
      status = BZ2_bzDecompress(&z);
      produced = out_.size() - z.avail_out;
      if (status == BZ_OK && z.avail_in == 0 && z.avail_out != 0) break;  // the input ran out
    }
    BZ2_bzDecompressEnd(&z);
    if (status != BZ_STREAM_END) {
      fail("its bzip2 stream " +
           std::string(status == BZ_OK ? "does not end where it should" : "is damaged"));
    }
    if (expected && produced != *expected) {
      fail("its bzip2 stream decodes to " + std::to_string(produced) + " bytes, for " +
           std::to_string(*expected));
    }
    out_.resize(produced);
    data.swap(out_);
  }

  std::vector<Filter> filters_;
  size_t chunk_bytes_;
  size_t element_bytes_;
  Bytes out_;  // each stage's output, swapped with its input
};

// "[a:b, c:d]": the selection [start, start + count) as Python slices.
std::string slices(const std::vector<hsize_t>& start, const std::vector<hsize_t>& count) {
  std::string s = "[";
  for (size_t d = 0; d < start.size(); ++d) {
    s += (d ? ", " : "") + std::to_string(start[d]) + ":" + std::to_string(start[d] + count[d]);
  }
  return s + "]";
}

std::string coordinates(const std::vector<hsize_t>& at) {
  std::string s = "[";
  for (size_t d = 0; d < at.size(); ++d) s += (d ? ", " : "") + std::to_string(at[d]);
  return s + "]";
}

// Where the selection [start, start + count) and the chunk at `origin` (dims `chunk`) overlap,
// copies its elements of `element` bytes from the chunk's buffer into `out`.
void copyOverlap(const uint8_t* chunk_data, const std::vector<hsize_t>& origin,
                 const std::vector<hsize_t>& chunk, const std::vector<hsize_t>& start,
                 const std::vector<hsize_t>& count, size_t element, uint8_t* out) {
  const size_t rank = chunk.size();
  std::vector<hsize_t> lo(rank), hi(rank);
  for (size_t d = 0; d < rank; ++d) {
    lo[d] = std::max(start[d], origin[d]);
    hi[d] = std::min(start[d] + count[d], origin[d] + chunk[d]);
    if (lo[d] >= hi[d]) return;
  }
  std::vector<hsize_t> at = lo;
  const size_t run = static_cast<size_t>(hi[rank - 1] - lo[rank - 1]) * element;
  while (true) {
    size_t from = 0, to = 0;
    for (size_t d = 0; d < rank; ++d) {
      from = from * chunk[d] + (at[d] - origin[d]);
      to = to * count[d] + (at[d] - start[d]);
    }
    std::memcpy(out + to * element, chunk_data + from * element, run);
    size_t d = rank - 1;  // the next row: the last dimension is copied whole
    while (d-- > 0) {
      if (++at[d] < hi[d]) break;
      at[d] = lo[d];
    }
    if (d == static_cast<size_t>(-1)) return;
  }
}

}  // namespace

void readHyperslab(hid_t dataset, hid_t mem_type, const std::vector<hsize_t>& start,
                   const std::vector<hsize_t>& count, void* out, const std::string& file,
                   const std::string& name) {
  const std::string what = name + slices(start, count);
  for (const hsize_t n : count) {
    if (n == 0) return;
  }
  H5Handle dcpl(H5Dget_create_plist(dataset));
  const int rank = static_cast<int>(start.size());
  std::vector<hsize_t> chunk(start.size());
  const bool filtered =
      dcpl && H5Pget_layout(dcpl.get()) == H5D_CHUNKED && H5Pget_nfilters(dcpl.get()) != 0;
  if (!filtered) {
    H5Handle file_space(H5Dget_space(dataset));
    H5Handle mem_space(H5Screate_simple(rank, count.data(), nullptr));
    if (H5Sselect_hyperslab(file_space.get(), H5S_SELECT_SET, start.data(), nullptr, count.data(),
                            nullptr) < 0 ||
        H5Dread(dataset, mem_type, mem_space.get(), file_space.get(), H5P_DEFAULT, out) < 0) {
      throwInFile(file, "cannot read " + what + " (truncated or corrupt file?)");
    }
    return;
  }
  std::vector<Filter> filters = pipelineOf(dcpl.get());
  for (const Filter& f : filters) {
    if (!decodedHere(f.id)) {
      throwInFile(file, name + " is compressed with " + filterName(f.id) +
                            ", which evkit does not decode (it decodes deflate, shuffle, "
                            "fletcher32, blosc, lzf, lz4 and bzip2; h5repack -f GZIP=4 "
                            "rewrites it)");
    }
  }
  const std::vector<hsize_t> shape = datasetShape(dataset);
  if (shape.size() != start.size() || H5Pget_chunk(dcpl.get(), rank, chunk.data()) != rank) {
    throwInFile(file, "cannot read " + what + ": its chunks are not of its rank");
  }
  H5Handle file_type(H5Dget_type(dataset));
  const size_t file_bytes = file_type ? H5Tget_size(file_type.get()) : 0;
  const size_t mem_bytes = H5Tget_size(mem_type);
  size_t elements = 1;
  for (const hsize_t c : chunk) {
    if (c == 0 || __builtin_mul_overflow(elements, static_cast<size_t>(c), &elements)) elements = 0;
  }
  size_t chunk_bytes = 0;
  if (file_bytes == 0 || elements == 0 ||
      __builtin_mul_overflow(elements, std::max(file_bytes, mem_bytes), &chunk_bytes) ||
      chunk_bytes > kMaxHdf5ChunkBytes) {
    throwInFile(file, name + ": chunks of " + std::to_string(elements) + " elements of " +
                          std::to_string(file_bytes) + " bytes (at most " +
                          std::to_string(kMaxHdf5ChunkBytes) + " bytes)");
  }
  chunk_bytes = elements * file_bytes;
  unsigned opts = 0;
  H5Pget_chunk_opts(dcpl.get(), &opts);
  const bool edges_unfiltered = opts & H5D_CHUNK_DONT_FILTER_PARTIAL_CHUNKS;
  ChunkDecoder decoder(std::move(filters), chunk_bytes, file_bytes);
  hsize_t base = 0;  // chunk addresses count from the end of the user block
  {
    H5Handle f(H5Iget_file_id(dataset));
    H5Handle fcpl(f ? H5Fget_create_plist(f.get()) : H5I_INVALID_HID);
    if (fcpl) H5Pget_userblock(fcpl.get(), &base);
  }

  std::vector<hsize_t> first(start.size()), last(start.size()), at(start.size());
  for (size_t d = 0; d < start.size(); ++d) {
    if (start[d] + count[d] > shape[d]) throwInFile(file, "cannot read " + what + ": past its end");
    first[d] = start[d] / chunk[d];
    last[d] = (start[d] + count[d] - 1) / chunk[d];
  }
  at = first;
  Bytes data, fill(mem_bytes);
  bool fill_read = false;
  std::vector<hsize_t> origin(start.size());
  while (true) {
    bool partial = false;
    for (size_t d = 0; d < start.size(); ++d) {
      origin[d] = at[d] * chunk[d];
      partial = partial || origin[d] + chunk[d] > shape[d];
    }
    unsigned skipped = 0;
    haddr_t address = HADDR_UNDEF;
    hsize_t stored = 0;
    const bool indexed =
        H5Dget_chunk_info_by_coord(dataset, origin.data(), &skipped, &address, &stored) >= 0;
    const auto fail = [&](const std::string& problem) {
      const std::string where = name + ", chunk at " + coordinates(origin) + ": " + problem;
      if (address == HADDR_UNDEF) throwInFile(file, where);
      throwAtByte(file, static_cast<int64_t>(address + base), where);
    };
    if (!indexed) fail("cannot find it in the chunk index");
    if (address == HADDR_UNDEF) {  // never written: the fill value
      if (!fill_read && H5Pget_fill_value(dcpl.get(), mem_type, fill.data()) < 0) {
        std::fill(fill.begin(), fill.end(), 0);
      }
      fill_read = true;
      data.resize(elements * mem_bytes);
      for (size_t e = 0; e < elements; ++e) {
        std::memcpy(data.data() + e * mem_bytes, fill.data(), mem_bytes);
      }
    } else {
      if (stored > kMaxHdf5ChunkBytes) fail(std::to_string(stored) + " bytes stored");
      data.resize(stored);
      if (H5Dread_chunk(dataset, H5P_DEFAULT, origin.data(), &skipped, data.data()) < 0) {
        fail("cannot read its " + std::to_string(stored) + " bytes (truncated file?)");
      }
      if (partial && edges_unfiltered) {
        if (data.size() != chunk_bytes) {
          fail(std::to_string(data.size()) + " bytes unfiltered, for " +
               std::to_string(chunk_bytes));
        }
      } else {
        decoder.decode(data, skipped, fail);
      }
      data.resize(elements * std::max(file_bytes, mem_bytes));
      if (H5Tconvert(file_type.get(), mem_type, elements, data.data(), nullptr, H5P_DEFAULT) < 0) {
        fail("cannot convert its values");
      }
    }
    copyOverlap(data.data(), origin, chunk, start, count, mem_bytes, static_cast<uint8_t*>(out));
    size_t d = start.size();
    while (d-- > 0) {
      if (at[d]++ < last[d]) break;
      at[d] = first[d];
    }
    if (d == static_cast<size_t>(-1)) return;
  }
}

void readRange(hid_t dataset, hid_t mem_type, hsize_t begin, hsize_t count, void* out,
               const std::string& file, const std::string& name) {
  readHyperslab(dataset, mem_type, {begin}, {count}, out, file, name);
}

}  // namespace evkit::detail
