// LZ4-frame and Zstandard (de)compression of whole buffers, as AEDAT 4.0 packets use them. Output
// grows only as data actually decompresses, up to a cap: a header that claims a huge content size
// cannot make us allocate it.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

namespace evkit::detail {

enum class Codec { kNone, kLz4, kZstd };

// Decompresses into out[0, out_size); `out` only grows (so that a reused buffer is not cleared for
// every packet). Returns false (with a reason) on corrupt input or output beyond max_output bytes.
bool decompress(Codec codec, const uint8_t* in, size_t in_size, std::vector<uint8_t>& out,
                size_t& out_size, size_t max_output, std::string& error);
void compress(Codec codec, const uint8_t* in, size_t in_size, std::vector<uint8_t>& out, int level);

}  // namespace evkit::detail
