#include "codec.h"

#include <lz4frame.h>
#include <zstd.h>

#include <algorithm>
#include <cstring>
#include <memory>
#include <stdexcept>

namespace evkit::detail {

namespace {

// LZ4 expands at most ~255:1, so the frame's declared content size is trusted only that far.
constexpr size_t kMaxLz4Ratio = 256;

void growTo(std::vector<uint8_t>& out, size_t n) {
  if (out.size() < n) out.resize(n);
}

// Doubles the output limit (up to max_output) when `produced` has reached it; false when it cannot.
bool makeRoom(std::vector<uint8_t>& out, size_t produced, size_t& limit, size_t max_output,
              std::string& error) {
  if (produced < limit) return true;
  if (limit >= max_output) {
    error = "decompressed packet larger than " + std::to_string(max_output) + " bytes";
    return false;
  }
  limit = std::min(max_output, limit * 2);
  growTo(out, limit);
  return true;
}

bool decompressLz4(const uint8_t* in, size_t in_size, std::vector<uint8_t>& out, size_t& out_size,
                   size_t max_output, std::string& error) {
  LZ4F_dctx* raw = nullptr;
  if (LZ4F_isError(LZ4F_createDecompressionContext(&raw, LZ4F_VERSION))) {
    error = "cannot create an LZ4 context";
    return false;
  }
  std::unique_ptr<LZ4F_dctx, decltype(&LZ4F_freeDecompressionContext)> ctx(
      raw, LZ4F_freeDecompressionContext);
  size_t consumed = 0;
  size_t limit = std::min<size_t>(max_output, std::max<size_t>(in_size * 4, 1 << 16));
  LZ4F_frameInfo_t frame_info;
  size_t header_bytes = in_size;
  if (!LZ4F_isError(LZ4F_getFrameInfo(ctx.get(), &frame_info, in, &header_bytes))) {
    consumed = header_bytes;
    if (frame_info.contentSize > 0) {
      limit = std::min<size_t>(
          {max_output, static_cast<size_t>(frame_info.contentSize), in_size * kMaxLz4Ratio + 4096});
    }
  }
  growTo(out, std::max<size_t>(limit, 1));
  size_t produced = 0;
  while (true) {
    if (!makeRoom(out, produced, limit, max_output, error)) return false;
    size_t dst = limit - produced, src = in_size - consumed;
    const size_t hint =
        LZ4F_decompress(ctx.get(), out.data() + produced, &dst, in + consumed, &src, nullptr);
    if (LZ4F_isError(hint)) {
      error = std::string("corrupt LZ4 data: ") + LZ4F_getErrorName(hint);
      return false;
    }
    produced += dst;
    consumed += src;
    if (hint == 0) break;  // frame complete
    if (consumed == in_size && produced < limit) {
      error = "truncated LZ4 frame";
      return false;
    }
  }
  out_size = produced;
  return true;
}

bool decompressZstd(const uint8_t* in, size_t in_size, std::vector<uint8_t>& out, size_t& out_size,
                    size_t max_output, std::string& error) {
  std::unique_ptr<ZSTD_DStream, decltype(&ZSTD_freeDStream)> ds(ZSTD_createDStream(),
                                                                ZSTD_freeDStream);
  ZSTD_initDStream(ds.get());
  size_t limit = std::min<size_t>(max_output, std::max<size_t>(in_size * 8, 1 << 16));
  growTo(out, limit);
  ZSTD_inBuffer input{in, in_size, 0};
  size_t produced = 0;
  while (true) {
    if (!makeRoom(out, produced, limit, max_output, error)) return false;
    ZSTD_outBuffer output{out.data() + produced, limit - produced, 0};
    const size_t ret = ZSTD_decompressStream(ds.get(), &output, &input);
    if (ZSTD_isError(ret)) {
      error = std::string("corrupt Zstandard data: ") + ZSTD_getErrorName(ret);
      return false;
    }
    produced += output.pos;
    if (ret == 0) break;
    if (input.pos == input.size && output.pos < output.size) {
      error = "truncated Zstandard frame";
      return false;
    }
  }
  out_size = produced;
  return true;
}

}  // namespace

bool decompress(Codec codec, const uint8_t* in, size_t in_size, std::vector<uint8_t>& out,
                size_t& out_size, size_t max_output, std::string& error) {
  switch (codec) {
    case Codec::kNone:
      if (in_size > max_output) {
        error = "packet larger than " + std::to_string(max_output) + " bytes";
        return false;
      }
      growTo(out, in_size);
      if (in_size > 0) std::memcpy(out.data(), in, in_size);
      out_size = in_size;
      return true;
    case Codec::kLz4:
      return decompressLz4(in, in_size, out, out_size, max_output, error);
    case Codec::kZstd:
      return decompressZstd(in, in_size, out, out_size, max_output, error);
  }
  return false;
}

void compress(Codec codec, const uint8_t* in, size_t in_size, std::vector<uint8_t>& out,
              int level) {
  switch (codec) {
    case Codec::kNone:
      out.assign(in, in + in_size);
      return;
    case Codec::kLz4: {
      LZ4F_preferences_t prefs;
      std::memset(&prefs, 0, sizeof(prefs));
      prefs.frameInfo.contentSize = in_size;
      // Independent 4 MB blocks: the reader can decompress straight into its buffer.
      prefs.frameInfo.blockSizeID = LZ4F_max4MB;
      prefs.frameInfo.blockMode = LZ4F_blockIndependent;
      prefs.compressionLevel = level;
      out.resize(LZ4F_compressFrameBound(in_size, &prefs));
      const size_t n = LZ4F_compressFrame(out.data(), out.size(), in, in_size, &prefs);
      if (LZ4F_isError(n)) throw std::runtime_error("LZ4 compression failed");
      out.resize(n);
      return;
    }
    case Codec::kZstd: {
      out.resize(ZSTD_compressBound(in_size));
      const size_t n = ZSTD_compress(out.data(), out.size(), in, in_size, level);
      if (ZSTD_isError(n)) throw std::runtime_error("Zstandard compression failed");
      out.resize(n);
      return;
    }
  }
}

}  // namespace evkit::detail
