// Reads of HDF5 datasets, with the chunks of a filtered dataset decoded by evkit.
//
// libhdf5 1.10.8 copies a whole chunk out of whatever its filter pipeline returns, and its
// built-in filters trust the sizes a file states: a damaged deflate stream that inflates to 11
// bytes, in a dataset of 2,048-byte chunks, makes it read 2,037 bytes past a heap buffer, and a
// scale-offset chunk of 21 bytes that claims full precision makes the filter itself copy 6,000
// bytes out of it. The built-in filters cannot be replaced (H5Zregister refuses "predefined
// filters"), so evkit reads each stored chunk as it is (H5Dread_chunk) and undoes the filters
// itself, checking every stage's size: a chunk decodes to exactly its chunk's bytes or is an
// error naming the dataset, the chunk and what was expected.
//
// Decoded here: deflate, shuffle, Fletcher32 (verified), Blosc (libblosc, every compressor of
// Debian's build), h5py's LZF, and the HDF Group's LZ4 and bzip2 plugins. Any other filter (szip,
// nbit, scale-offset, other plugins) is refused with its name: libhdf5's decoders and plugins are
// not safe on a damaged file.
#pragma once

#include <hdf5.h>

#include <string>
#include <vector>

namespace evkit::detail {

// Reads the hyperslab [start, start + count) of `dataset` (rank = start.size()) into `out`, in C
// order, converted to `mem_type`. Throws evkit::Error "FILE: NAME ..." when it cannot.
void readHyperslab(hid_t dataset, hid_t mem_type, const std::vector<hsize_t>& start,
                   const std::vector<hsize_t>& count, void* out, const std::string& file,
                   const std::string& name);

// Reads elements [begin, begin + count) of a 1-D dataset, converting to mem_type.
void readRange(hid_t dataset, hid_t mem_type, hsize_t begin, hsize_t count, void* out,
               const std::string& file, const std::string& name);

}  // namespace evkit::detail
