// Size-checked replacements for HDF5's built-in deflate and shuffle filters.
//
// libhdf5 1.10.8 copies a whole chunk out of whatever its filter pipeline returns: a damaged
// deflate stream that inflates to 11 bytes, in a dataset of 2,048-byte chunks, makes it read
// 2,037 bytes past the end of a heap buffer (found by fuzzing). The library's filters do not know
// the chunk's size; these do: the reader states it (ChunkSizeScope) around each read, and a stream
// that decodes to any other size is an error, never a short buffer. Writing is unchanged (the
// same zlib stream and byte shuffle), so files stay readable by every HDF5 build.
#pragma once

#include <hdf5.h>

#include <cstddef>

namespace evkit::detail {

// Registers the checked filters in place of the built-in ones (once per process).
void useCheckedFilters();

// While alive, the filters on this thread expect chunks of the dataset's chunk size in bytes
// (its chunk dimensions times its element size); 0 (not chunked) disables the check.
class ChunkSizeScope {
 public:
  explicit ChunkSizeScope(hid_t dataset);
  ~ChunkSizeScope();
  ChunkSizeScope(const ChunkSizeScope&) = delete;
  ChunkSizeScope& operator=(const ChunkSizeScope&) = delete;

 private:
  size_t previous_;
};

}  // namespace evkit::detail
