// Checks, from the file's own bytes, the sizes that libhdf5 trusts before it allocates.
//
// Debian 12's libhdf5 1.10.8 allocates an object header's first chunk at the size the header
// states, before it checks it against the file: a damaged size field asks for hundreds of
// gigabytes inside H5Fopen or H5Dopen2. evkit reads the superblock and each object header it is
// about to open (HDF5 File Format Specification 3.0, sections II.A and IV.A.1) and refuses one that
// claims more bytes than the file holds, so the library is only asked for what the file can back.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "binary_file.h"

namespace evkit::detail {

// The largest object header chunk, local heap or data chunk evkit lets libhdf5 allocate: real
// header chunks hold a few kB and real data chunks a few MB (h5py aims at 1 MB, evkit writes 1 MB).
constexpr uint64_t kMaxHdf5ChunkBytes = uint64_t{1} << 26;

class Hdf5Precheck {
 public:
  // Reads the superblock (at byte 0 or after a user block of 512, 1024, 2048, ... bytes); throws
  // evkit::Error "FILE: byte N: ..." when it is missing, of an unknown version or inconsistent,
  // and when the root group's object header does not fit in the file.
  explicit Hdf5Precheck(std::string path);

  // Checks the object header at `address` (relative to the base address, as HDF5 links store
  // addresses); `what` names the object in the error message.
  void checkObjectHeader(uint64_t address, const std::string& what) const;

 private:
  void checkLocalHeap(uint64_t address, const std::string& what) const;
  // A dataspace message's element count, and a compact layout message's data bytes (nullopt:
  // not a compact layout, or a dataspace too short to tell).
  std::optional<uint64_t> dataspaceElements(const uint8_t* message, uint64_t size) const;
  std::optional<uint64_t> compactBytes(const uint8_t* message, uint64_t size) const;
  // Returns the pipeline's count of filters.
  int checkFilterPipeline(const uint8_t* message, uint64_t size, int64_t at,
                          const std::string& what) const;
  void checkLayout(const uint8_t* message, uint64_t size, int64_t at, bool filtered,
                   const std::string& what) const;
  // Returns the bytes the datatype's encoding takes; `depth` counts the datatypes it is within.
  uint64_t checkDatatype(const uint8_t* message, uint64_t size, int64_t at, const std::string& what,
                         int depth = 0) const;
  void checkAttribute(const uint8_t* message, uint64_t size, int64_t at,
                      const std::string& what) const;
  // Whether `length` bytes from `address` (counted from the base) lie inside the file.
  bool spans(uint64_t address, uint64_t length) const;
  // The chunk B-tree at `address`, read from the message at byte `cited`; chunks without filters
  // hold `unfiltered_bytes` each (0: the dataset has filters).
  void checkChunkIndex(uint64_t address, int64_t cited, int rank, uint64_t unfiltered_bytes,
                       const std::string& what) const;
  void checkGroupIndex(uint64_t address, int64_t cited, const std::string& what) const;
  // Walks the version 1 B-tree of `type` at `address` (read at byte `cited`; keys of `key` bytes)
  // and hands each leaf's key, child address and node position to `leaf`; `index` names it in the
  // error message.
  void checkBTree(
      uint64_t address, int64_t cited, int type, size_t key, const std::string& index,
      const std::function<void(const uint8_t* key, uint64_t child, int64_t at)>& leaf) const;

  std::string path_;
  mutable BinaryFile file_;  // the checks read it at the offsets they need
  int64_t file_size_ = 0;
  uint64_t base_ = 0;
  uint64_t address_limit_ = 0;  // file_size_ - base_: every address lies below it
  int offset_bytes_ = 0;        // 2, 4 or 8: the width of an address
  int length_bytes_ = 0;        // 2, 4 or 8: the width of a length
};

}  // namespace evkit::detail
