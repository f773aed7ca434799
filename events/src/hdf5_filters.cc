#include "hdf5_filters.h"

#include <zlib.h>

#include <algorithm>
#include <cstring>
#include <mutex>

#include "hdf5_precheck.h"
#include "hdf5_util.h"

namespace evkit::detail {
namespace {

thread_local size_t t_chunk_bytes = 0;  // what a decoded chunk must hold; 0: unknown

// Replaces *buf (allocated by the library) with `out` of `size` bytes.
size_t replaceBuffer(void** buf, size_t* buf_size, void* out, size_t size, size_t capacity) {
  H5free_memory(*buf);
  *buf = out;
  *buf_size = capacity;
  return size;
}

size_t inflateChunk(size_t nbytes, size_t* buf_size, void** buf) {
  if (t_chunk_bytes > kMaxHdf5ChunkBytes) return 0;
  z_stream z{};
  if (inflateInit(&z) != Z_OK) return 0;
  // Known size: exactly that, and the stream must end there. Unknown: grow as the library does.
  size_t capacity = t_chunk_bytes ? t_chunk_bytes : std::max<size_t>(nbytes * 4, 64);
  auto* out = static_cast<unsigned char*>(H5allocate_memory(capacity, false));
  if (!out) return inflateEnd(&z), 0;
  z.next_in = static_cast<Bytef*>(*buf);
  z.avail_in = static_cast<uInt>(nbytes);
  int status = Z_OK;
  while (status == Z_OK) {
    if (z.total_out == capacity) {
      if (t_chunk_bytes) break;  // more than a chunk: damaged
      void* grown = H5resize_memory(out, capacity * 2);
      if (!grown) break;
      out = static_cast<unsigned char*>(grown);
      capacity *= 2;
    }
    z.next_out = out + z.total_out;
    z.avail_out = static_cast<uInt>(capacity - z.total_out);
    status = inflate(&z, Z_SYNC_FLUSH);
    if (status == Z_OK && z.avail_in == 0 && z.avail_out != 0) break;  // input ran out early
  }
  const size_t produced = z.total_out;
  inflateEnd(&z);
  if (status != Z_STREAM_END || (t_chunk_bytes && produced != t_chunk_bytes)) {
    H5free_memory(out);
    return 0;
  }
  return replaceBuffer(buf, buf_size, out, produced, capacity);
}

size_t deflateChunk(unsigned level, size_t nbytes, size_t* buf_size, void** buf) {
  uLongf bound = compressBound(static_cast<uLong>(nbytes));
  auto* out = static_cast<unsigned char*>(H5allocate_memory(bound, false));
  if (!out) return 0;
  if (compress2(out, &bound, static_cast<const Bytef*>(*buf), static_cast<uLong>(nbytes),
                static_cast<int>(std::min(level, 9u))) != Z_OK) {
    H5free_memory(out);
    return 0;
  }
  return replaceBuffer(buf, buf_size, out, bound, compressBound(static_cast<uLong>(nbytes)));
}

// HDF5 filter callback for deflate (cd_values[0]: the level).
size_t deflateFilter(unsigned flags, size_t cd_nelmts, const unsigned cd_values[], size_t nbytes,
                     size_t* buf_size, void** buf) {
  if (flags & H5Z_FLAG_REVERSE) return inflateChunk(nbytes, buf_size, buf);
  return deflateChunk(cd_nelmts > 0 ? cd_values[0] : 6, nbytes, buf_size, buf);
}

// HDF5 filter callback for the byte shuffle (cd_values[0]: the element size, set at creation):
// byte b of element e goes to plane b, position e; the bytes that do not fill an element stay.
size_t shuffleFilter(unsigned flags, size_t cd_nelmts, const unsigned cd_values[], size_t nbytes,
                     size_t* buf_size, void** buf) {
  if ((flags & H5Z_FLAG_REVERSE) && t_chunk_bytes && nbytes != t_chunk_bytes) return 0;
  const size_t width = cd_nelmts > 0 ? cd_values[0] : 1;
  if (width <= 1 || nbytes < width) return nbytes;
  auto* out = static_cast<unsigned char*>(H5allocate_memory(nbytes, false));
  if (!out) return 0;
  const auto* in = static_cast<const unsigned char*>(*buf);
  const size_t count = nbytes / width;
  for (size_t e = 0; e < count; ++e) {
    for (size_t b = 0; b < width; ++b) {
      if (flags & H5Z_FLAG_REVERSE) {
        out[e * width + b] = in[b * count + e];
      } else {
        out[b * count + e] = in[e * width + b];
      }
    }
  }
  std::memcpy(out + count * width, in + count * width, nbytes - count * width);
  return replaceBuffer(buf, buf_size, out, nbytes, nbytes);
}

// The shuffle filter needs its element size recorded when a dataset is created.
herr_t shuffleSetLocal(hid_t dcpl, hid_t type, hid_t /*space*/) {
  unsigned flags = 0;
  size_t n = 1;
  unsigned values[1] = {0};
  if (H5Pget_filter_by_id2(dcpl, H5Z_FILTER_SHUFFLE, &flags, &n, values, 0, nullptr, nullptr) < 0)
    return -1;
  values[0] = static_cast<unsigned>(H5Tget_size(type));
  return H5Pmodify_filter(dcpl, H5Z_FILTER_SHUFFLE, flags, 1, values);
}

}  // namespace

void useCheckedFilters() {
  static std::once_flag once;
  std::call_once(once, [] {
    static const H5Z_class2_t deflate = {
        H5Z_CLASS_T_VERS, H5Z_FILTER_DEFLATE, 1, 1, "deflate (size-checked)", nullptr,
        nullptr,          deflateFilter};
    static const H5Z_class2_t shuffle = {
        H5Z_CLASS_T_VERS, H5Z_FILTER_SHUFFLE, 1, 1, "shuffle (size-checked)", nullptr,
        shuffleSetLocal,  shuffleFilter};
    H5Zregister(&deflate);
    H5Zregister(&shuffle);
  });
}

ChunkSizeScope::ChunkSizeScope(hid_t dataset) : previous_(t_chunk_bytes) {
  size_t bytes = 0;
  H5Handle dcpl(H5Dget_create_plist(dataset));
  if (dcpl && H5Pget_layout(dcpl.get()) == H5D_CHUNKED) {
    hsize_t dims[32];
    const int rank = H5Pget_chunk(dcpl.get(), 32, dims);
    H5Handle type(H5Dget_type(dataset));
    bytes = type ? H5Tget_size(type.get()) : 0;
    for (int d = 0; d < rank; ++d) bytes *= static_cast<size_t>(dims[d]);
    if (rank <= 0) bytes = 0;
  }
  t_chunk_bytes = bytes;
}

ChunkSizeScope::~ChunkSizeScope() { t_chunk_bytes = previous_; }

}  // namespace evkit::detail
