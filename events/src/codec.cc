#include "codec.h"

#include <lz4frame.h>
#include <zstd.h>

#include <cstring>
#include <memory>
#include <stdexcept>

namespace evkit::detail {

namespace {

bool decompressLz4(const uint8_t* in, size_t in_size, std::vector<uint8_t>& out, size_t max_output,
                   std::string& error) {
  LZ4F_dctx* raw = nullptr;
  if (LZ4F_isError(LZ4F_createDecompressionContext(&raw, LZ4F_VERSION))) {
    error = "cannot create an LZ4 context";
    return false;
  }
  std::unique_ptr<LZ4F_dctx, decltype(&LZ4F_freeDecompressionContext)> ctx(raw, LZ4F_freeDecompressionContext);
  out.resize(std::min<size_t>(max_output, std::max<size_t>(in_size * 4, 1 << 16)));
  size_t produced = 0, consumed = 0;
  while (true) {
    if (produced == out.size()) {
      if (out.size() >= max_output) {
        error = "decompressed packet larger than " + std::to_string(max_output) + " bytes";
        return false;
      }
      out.resize(std::min(max_output, out.size() * 2));
    }
    size_t dst = out.size() - produced, src = in_size - consumed;
    const size_t hint = LZ4F_decompress(ctx.get(), out.data() + produced, &dst, in + consumed, &src, nullptr);
    if (LZ4F_isError(hint)) {
      error = std::string("corrupt LZ4 data: ") + LZ4F_getErrorName(hint);
      return false;
    }
    produced += dst;
    consumed += src;
    if (hint == 0) break;  // frame complete
    if (consumed == in_size && produced < out.size()) {
      error = "truncated LZ4 frame";
      return false;
    }
  }
  out.resize(produced);
  return true;
}

bool decompressZstd(const uint8_t* in, size_t in_size, std::vector<uint8_t>& out, size_t max_output,
                    std::string& error) {
  std::unique_ptr<ZSTD_DStream, decltype(&ZSTD_freeDStream)> ds(ZSTD_createDStream(), ZSTD_freeDStream);
  ZSTD_initDStream(ds.get());
  out.resize(std::min<size_t>(max_output, std::max<size_t>(in_size * 4, 1 << 16)));
  ZSTD_inBuffer input{in, in_size, 0};
  size_t produced = 0;
  while (true) {
    if (produced == out.size()) {
      if (out.size() >= max_output) {
        error = "decompressed packet larger than " + std::to_string(max_output) + " bytes";
        return false;
      }
      out.resize(std::min(max_output, out.size() * 2));
    }
    ZSTD_outBuffer output{out.data() + produced, out.size() - produced, 0};
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
  out.resize(produced);
  return true;
}

}  // namespace

bool decompress(Codec codec, const uint8_t* in, size_t in_size, std::vector<uint8_t>& out, size_t max_output,
                std::string& error) {
  switch (codec) {
    case Codec::kNone:
      if (in_size > max_output) {
        error = "packet larger than " + std::to_string(max_output) + " bytes";
        return false;
      }
      out.assign(in, in + in_size);
      return true;
    case Codec::kLz4:
      return decompressLz4(in, in_size, out, max_output, error);
    case Codec::kZstd:
      return decompressZstd(in, in_size, out, max_output, error);
  }
  return false;
}

void compress(Codec codec, const uint8_t* in, size_t in_size, std::vector<uint8_t>& out, int level) {
  switch (codec) {
    case Codec::kNone:
      out.assign(in, in + in_size);
      return;
    case Codec::kLz4: {
      LZ4F_preferences_t prefs;
      std::memset(&prefs, 0, sizeof(prefs));
      prefs.frameInfo.contentSize = in_size;
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
