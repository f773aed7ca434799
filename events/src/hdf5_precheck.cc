#include "hdf5_precheck.h"

#include <cstring>
#include <functional>
#include <optional>
#include <set>
#include <vector>

#include "binary_file.h"
#include "evkit/base/error.h"

namespace evkit::detail {
namespace {

constexpr uint8_t kSignature[8] = {0x89, 'H', 'D', 'F', '\r', '\n', 0x1a, '\n'};
constexpr int kContinuation = 0x10;  // object header message types
constexpr int kDataspace = 0x01;
constexpr int kDatatype = 0x03;
constexpr int kLayout = 0x08;
constexpr int kFilterPipeline = 0x0b;
constexpr int kAttribute = 0x0c;
constexpr int kVariableLength = 9;    // datatype class
constexpr int kMaxTypeDepth = 8;      // datatypes within datatypes
constexpr int kSharedMessage = 0x02;  // object header message flag
// A shared datatype message refers to a committed datatype's object header instead of holding the
// datatype: event files do not use them, and evkit does not check them.
constexpr const char* kSharedDatatype = "a shared (committed) datatype, which evkit does not read";
constexpr int kSymbolTable = 0x11;
constexpr int kCompactLayout = 0;
constexpr int kChunkedLayout = 2;
constexpr size_t kMaxChunks = 4096;              // object header chunks of one object
constexpr size_t kMaxIndexNodes = 1 << 16;       // nodes of one B-tree
constexpr int kGroupNodes = 0, kChunkNodes = 1;  // version 1 B-tree node types

uint64_t loadLe(const uint8_t* p, int bytes) {
  uint64_t v = 0;
  for (int i = bytes - 1; i >= 0; --i) v = (v << 8) | p[i];
  return v;
}

bool undefinedAddress(uint64_t address, int offset_bytes) {
  return offset_bytes == 8 ? address == ~uint64_t{0}
                           : address == (uint64_t{1} << (8 * offset_bytes)) - 1;
}

}  // namespace

Hdf5Precheck::Hdf5Precheck(std::string path) : path_(std::move(path)), file_(path_) {
  file_size_ = file_.size();
  // The superblock sits at 0, 512, 1024, 2048, ... (a user block may come first).
  int64_t at = -1;
  for (int64_t candidate = 0; candidate + 8 <= file_size_;
       candidate = candidate == 0 ? 512 : candidate * 2) {
    uint8_t signature[8];
    file_.seek(candidate);
    file_.readExact(signature, 8, "the HDF5 signature");
    if (std::memcmp(signature, kSignature, 8) == 0) {
      at = candidate;
      break;
    }
  }
  if (at < 0) file_.failAt(0, "no HDF5 superblock signature (not an HDF5 file)");

  uint8_t sb[128] = {};
  file_.seek(at);
  const size_t got = file_.read(sb, sizeof(sb));
  const int version = sb[8];
  int offset_bytes = 0;
  size_t fields = 0;  // where the base address starts
  if (version == 0 || version == 1) {
    offset_bytes = sb[13];
    length_bytes_ = sb[14];
    fields = version == 0 ? 24 : 28;
  } else if (version == 2 || version == 3) {
    offset_bytes = sb[9];
    length_bytes_ = sb[10];
    fields = 12;
  } else {
    file_.failAt(at + 8, "unknown HDF5 superblock version " + std::to_string(version));
  }
  const auto usable = [](int bytes) { return bytes == 2 || bytes == 4 || bytes == 8; };
  if (!usable(offset_bytes) || !usable(length_bytes_)) {
    file_.failAt(at + 9, "HDF5 superblock with " + std::to_string(offset_bytes) +
                             "-byte addresses and " + std::to_string(length_bytes_) +
                             "-byte lengths");
  }
  // v0/v1: base, free space, end of file, driver info, then the root group's symbol table entry
  // (link name offset, object header address); v2/v3: base, extension, end of file, root group.
  const size_t root_field = fields + static_cast<size_t>(offset_bytes) * (version <= 1 ? 5 : 3);
  if (root_field + offset_bytes > got) file_.failAt(at, "truncated HDF5 superblock");
  // Addresses count from the base address, which libhdf5 (1.10, H5F__super_read) takes to be the
  // superblock's own position whatever the superblock states: a stated base of 4 once sent the
  // checks to other bytes than the library reads (found by fuzzing).
  base_ = static_cast<uint64_t>(at);
  address_limit_ = static_cast<uint64_t>(file_size_) - base_;
  offset_bytes_ = offset_bytes;
  checkObjectHeader(loadLe(sb + root_field, offset_bytes), "the root group");
}

bool Hdf5Precheck::spans(uint64_t address, uint64_t length) const {
  return !undefinedAddress(address, offset_bytes_) && address <= address_limit_ &&
         length <= address_limit_ - address;
}

void Hdf5Precheck::checkObjectHeader(uint64_t address, const std::string& what) const {
  const auto fail = [&](int64_t at, const std::string& problem) {
    throwAtByte(path_, at, "object header of " + what + ": " + problem);
  };
  // A chunk lies inside the file; its bytes are read (chunks are small in real files).
  const auto inFile = [&](uint64_t relative, uint64_t length, int64_t cited) -> int64_t {
    if (!spans(relative, length)) {
      fail(cited, "a chunk of " + std::to_string(length) + " bytes at address " +
                      std::to_string(relative) + " lies outside the file");
    }
    if (length > kMaxHdf5ChunkBytes)
      fail(cited, "a chunk of " + std::to_string(length) + " bytes (implausible)");
    return static_cast<int64_t>(base_ + relative);
  };
  const int64_t at = inFile(address, 16, static_cast<int64_t>(base_));
  file_.seek(at);
  uint8_t h[48] = {};
  const size_t got = file_.read(h, sizeof(h));
  int version = 0;
  bool creation_order = false;  // v2: each message carries a 2-byte creation index
  int64_t messages_at = 0;
  uint64_t messages_bytes = 0;
  if (got >= 6 && std::memcmp(h, "OHDR", 4) == 0 && h[4] == 2) {
    // Version 2: signature, version, flags, [4 times], [2 attribute phase limits], chunk #0 size.
    version = 2;
    const uint8_t flags = h[5];
    creation_order = (flags & 0x04) != 0;
    int64_t prefix = 6 + ((flags & 0x20) ? 16 : 0) + ((flags & 0x10) ? 4 : 0);
    const int width = 1 << (flags & 3);
    if (got < static_cast<size_t>(prefix + width)) fail(at, "truncated");
    messages_bytes = loadLe(h + prefix, width);
    messages_at = at + prefix + width;
    // The messages, then the checksum after them: one call for both wrapped a chunk size of
    // 2^64 - 1 to 3 bytes, which then failed an allocation (found by fuzzing).
    const uint64_t messages = address + static_cast<uint64_t>(prefix + width);
    inFile(messages, messages_bytes, at);
    inFile(messages + messages_bytes, 4, at);
  } else if (got >= 16 && h[0] == 1) {
    // Version 1: version, reserved, message count, reference count, header size, padding.
    version = 1;
    messages_bytes = loadLe(h + 8, 4);
    messages_at = at + 16;
    inFile(address + 16, messages_bytes, at);
  } else {
    fail(at, "neither version 1 nor version 2 (damaged?)");
  }

  // Every continuation chunk the messages point to must lie in the file too: the library loads
  // each one at its stated length.
  struct Chunk {
    int64_t at;
    uint64_t bytes;
  };
  std::vector<Chunk> pending = {{messages_at, messages_bytes}};
  std::set<int64_t> seen = {messages_at};
  const size_t header_bytes = version == 1 ? 8 : (creation_order ? 6 : 4);
  std::vector<uint8_t> chunk;
  // A compact dataset's data is in its layout message, which libhdf5 1.10.8 reads at the size the
  // dataspace and datatype give, past the message when they claim more (a heap overflow inside
  // H5Dread, found by fuzzing): the three are compared once every message is read.
  std::optional<uint64_t> elements, element_bytes;
  std::optional<std::vector<uint8_t>> layout;  // a message may be empty
  int64_t layout_at = 0;
  // Chunks without filters are read at their stored size and copied out at the chunk's: they are
  // checked against it, once every message is read. Filtered: every pipeline message names one.
  int pipelines = 0;
  bool filtered = true;
  while (!pending.empty()) {
    const Chunk c = pending.back();
    pending.pop_back();
    chunk.resize(c.bytes);
    file_.seek(c.at);
    file_.readExact(chunk.data(), chunk.size(), "an object header chunk");
    for (size_t pos = 0; pos + header_bytes <= chunk.size();) {
      const int type = version == 1 ? loadLe(&chunk[pos], 2) : chunk[pos];
      const uint64_t size = version == 1 ? loadLe(&chunk[pos + 2], 2) : loadLe(&chunk[pos + 1], 2);
      const bool shared = (chunk[pos + (version == 1 ? 4 : 3)] & kSharedMessage) != 0;
      const size_t data = pos + header_bytes;
      if (size > chunk.size() - data)
        fail(c.at + static_cast<int64_t>(pos), "a message runs past its chunk");
      if (type == kContinuation) {
        if (size < static_cast<uint64_t>(offset_bytes_ + length_bytes_))
          fail(c.at + static_cast<int64_t>(pos), "a short continuation message");
        const uint64_t next = loadLe(&chunk[data], offset_bytes_);
        const uint64_t length = loadLe(&chunk[data + offset_bytes_], length_bytes_);
        int64_t next_at = inFile(next, length, c.at + static_cast<int64_t>(pos));
        uint64_t next_bytes = length;
        if (version == 2) {  // "OCHK", the messages, a checksum
          if (length < 8)
            fail(next_at, "a continuation chunk of " + std::to_string(length) + " bytes");
          next_at += 4;
          next_bytes -= 8;
        }
        if (seen.size() > kMaxChunks)
          fail(at, "more than " + std::to_string(kMaxChunks) + " chunks");
        if (seen.insert(next_at).second) pending.push_back({next_at, next_bytes});
      } else if (type == kDataspace) {
        elements = dataspaceElements(&chunk[data], size);
      } else if (type == kDatatype) {
        if (shared) fail(c.at + static_cast<int64_t>(pos), kSharedDatatype);
        checkDatatype(&chunk[data], size, c.at + static_cast<int64_t>(data), what);
        if (size >= 8) element_bytes = loadLe(&chunk[data + 4], 4);
      } else if (type == kAttribute) {
        checkAttribute(&chunk[data], size, c.at + static_cast<int64_t>(data), what);
      } else if (type == kLayout) {
        layout.emplace(chunk.begin() + static_cast<std::ptrdiff_t>(data),
                       chunk.begin() + static_cast<std::ptrdiff_t>(data + size));
        layout_at = c.at + static_cast<int64_t>(data);
      } else if (type == kFilterPipeline) {
        ++pipelines;
        filtered =
            checkFilterPipeline(&chunk[data], size, c.at + static_cast<int64_t>(data), what) > 0 &&
            filtered;
      } else if (type == kSymbolTable) {
        // An old-style group: a B-tree of symbol nodes and the local heap of their names; the
        // library loads the heap's data segment at its stated size.
        if (size < static_cast<uint64_t>(2 * offset_bytes_))
          fail(c.at + static_cast<int64_t>(pos), "a short symbol table message");
        checkGroupIndex(loadLe(&chunk[data], offset_bytes_), c.at + static_cast<int64_t>(data),
                        what);
        checkLocalHeap(loadLe(&chunk[data + offset_bytes_], offset_bytes_), what);
      }
      pos = data + size;
    }
  }
  if (!layout) return;
  checkLayout(layout->data(), layout->size(), layout_at, pipelines > 0 && filtered, what);
  const std::optional<uint64_t> compact_bytes = compactBytes(layout->data(), layout->size());
  if (compact_bytes && elements && element_bytes &&
      (*element_bytes != 0 && *elements > *compact_bytes / *element_bytes)) {
    throwAtByte(path_, layout_at,
                "data layout of " + what + ": compact data of " + std::to_string(*compact_bytes) +
                    " bytes for " + std::to_string(*elements) + " elements of " +
                    std::to_string(*element_bytes) + " bytes");
  }
}

std::optional<uint64_t> Hdf5Precheck::dataspaceElements(const uint8_t* m, uint64_t size) const {
  // Dataspace message, section IV.A.2.b: version, rank, flags, [v1: 5 reserved bytes; v2: type
  // (2: null)], then the dimensions (L each). The product saturates: only its size against the
  // bytes that hold the data (a compact dataset's, an attribute's value) matters.
  if (size < 4) return std::nullopt;
  const int version = m[0], rank = m[1];
  if (version == 2 && m[3] == 2) return 0;
  const uint64_t dims_at = version == 1 ? 8 : 4;
  if (dims_at + static_cast<uint64_t>(rank) * length_bytes_ > size) return std::nullopt;
  uint64_t n = 1;
  for (int d = 0; d < rank; ++d) {
    const uint64_t dim =
        loadLe(m + dims_at + static_cast<uint64_t>(d) * length_bytes_, length_bytes_);
    n = dim != 0 && n > UINT64_MAX / dim ? UINT64_MAX : n * dim;
  }
  return n;
}

std::optional<uint64_t> Hdf5Precheck::compactBytes(const uint8_t* m, uint64_t size) const {
  // Data layout message, section IV.A.2.i, of the compact class: versions 3-4 (version, class,
  // the data's size in 2 bytes, the data) and 1-2 (version, dimensionality, class, 5 reserved
  // bytes, 4-byte dimensions, the data's size in 4 bytes, the data). The size stated is what the
  // message holds: no more than the message's own bytes.
  const int version = size >= 3 ? m[0] : 0;
  uint64_t stated = 0, at = 0;
  if ((version == 3 || version == 4) && m[1] == kCompactLayout && size >= 4) {
    stated = loadLe(m + 2, 2);
    at = 4;
  } else if ((version == 1 || version == 2) && m[2] == kCompactLayout) {
    at = 8 + 4 * static_cast<uint64_t>(m[1]);
    if (at + 4 > size) return 0;
    stated = loadLe(m + at, 4);
    at += 4;
  } else {
    return std::nullopt;
  }
  return std::min(stated, size - at);
}

void Hdf5Precheck::checkLocalHeap(uint64_t address, const std::string& what) const {
  // "HEAP", version 0, 3 reserved bytes, data segment size (L), free list offset (L), data segment
  // address (O): section III.D of the specification.
  const auto fail = [&](int64_t at, const std::string& problem) {
    throwAtByte(path_, at, "local heap of " + what + ": " + problem);
  };
  const size_t prefix =
      8 + 2 * static_cast<size_t>(length_bytes_) + static_cast<size_t>(offset_bytes_);
  if (!spans(address, prefix)) {
    fail(static_cast<int64_t>(base_),
         "address " + std::to_string(address) + " lies outside the file");
  }
  const int64_t at = static_cast<int64_t>(base_ + address);
  file_.seek(at);
  uint8_t h[40] = {};
  file_.readExact(h, prefix, "a local heap prefix");
  if (std::memcmp(h, "HEAP", 4) != 0) fail(at, "no HEAP signature");
  const uint64_t bytes = loadLe(h + 8, length_bytes_);
  const uint64_t segment = loadLe(h + 8 + 2 * length_bytes_, offset_bytes_);
  if (!spans(segment, bytes) || bytes > kMaxHdf5ChunkBytes) {
    fail(at, "a data segment of " + std::to_string(bytes) + " bytes at address " +
                 std::to_string(segment) + " lies outside the file");
  }
  // The free list: blocks inside the data segment, each starting with the next block's offset and
  // its own size (L each); 1 ends the list. The library follows it without a bound and allocates a
  // node per block, so a list that loops back asks for memory until none is left. Blocks do not
  // overlap, so a list longer than the segment holds blocks is a loop.
  const uint64_t kEnd = 1;
  const uint64_t entry = 2 * static_cast<uint64_t>(length_bytes_);
  uint64_t block = loadLe(h + 8 + length_bytes_, length_bytes_);
  int64_t cited = at + 8 + length_bytes_;  // where the offset of `block` is stored
  for (uint64_t blocks = 0; block != kEnd; ++blocks) {
    if (block > bytes || entry > bytes - block) {
      fail(cited, "a free block at offset " + std::to_string(block) + " lies outside its " +
                      std::to_string(bytes) + "-byte data segment");
    }
    if (blocks > bytes / entry) fail(cited, "the free list loops back on itself");
    uint8_t b[16] = {};
    file_.seek(static_cast<int64_t>(base_ + segment + block));
    file_.readExact(b, entry, "a local heap free block");
    const uint64_t size = loadLe(b + length_bytes_, length_bytes_);
    cited = static_cast<int64_t>(base_ + segment + block);
    if (size > bytes - block) {
      fail(cited, "a free block of " + std::to_string(size) + " bytes at offset " +
                      std::to_string(block) + " runs past its " + std::to_string(bytes) +
                      "-byte data segment");
    }
    block = loadLe(b, length_bytes_);
  }
}

int Hdf5Precheck::checkFilterPipeline(const uint8_t* m, uint64_t size, int64_t at,
                                      const std::string& what) const {
  // Filter pipeline message, section IV.A.2.l: version, the filters' count, [v1: 6 reserved bytes],
  // then each filter: its identification value (2 bytes), [its name's length (2): v1, or v2 from
  // 256], flags (2), the client data's count (2), [the name, NUL-terminated: v1 padded to 8 bytes],
  // the client data (4 bytes each), [v1: 4 bytes of padding after an odd count]. libhdf5 1.10.8
  // decodes as many filters as the count says and takes each name's length with strlen, past the
  // message where it runs out (a heap overflow inside H5Dopen2, found by fuzzing).
  const auto fail = [&](const std::string& problem) {
    throwAtByte(path_, at, "filter pipeline of " + what + ": " + problem);
  };
  if (size < 2) fail("truncated");
  const int version = m[0];
  if (version != 1 && version != 2) fail("unknown version " + std::to_string(version));
  uint64_t pos = version == 1 ? 8 : 2;
  for (int f = 0; f < m[1]; ++f) {
    if (pos + 2 > size)
      fail(std::to_string(m[1]) + " filters, truncated after " + std::to_string(f));
    const int id = static_cast<int>(loadLe(m + pos, 2));
    const bool named = version == 1 || id >= 256;
    const uint64_t fields = named ? 8 : 6;
    if (pos + fields > size)
      fail(std::to_string(m[1]) + " filters, truncated after " + std::to_string(f));
    const uint64_t name = named ? loadLe(m + pos + 2, 2) : 0;
    const uint64_t values = loadLe(m + pos + fields - 2, 2);
    const uint64_t name_bytes = version == 1 ? (name + 7) / 8 * 8 : name;
    const uint64_t name_at = pos + fields;
    pos = name_at + name_bytes + 4 * values + (version == 1 && values % 2 == 1 ? 4 : 0);
    if (pos > size) fail(std::to_string(m[1]) + " filters, truncated after " + std::to_string(f));
    if (name > 0 && std::memchr(m + name_at, 0, name) == nullptr)
      fail("the name of filter " + std::to_string(id) + " does not end within its " +
           std::to_string(name) + " bytes");
  }
  return m[1];
}

void Hdf5Precheck::checkLayout(const uint8_t* m, uint64_t size, int64_t at, bool filtered,
                               const std::string& what) const {
  // A chunked dataset's chunk dimensions divide in the library: a zero one is a SIGFPE there.
  // Data layout message, section IV.A.2.i: versions 1-2 (dimensionality, class, 5 reserved bytes,
  // an address unless compact, 4-byte dimensions), 3 (class, dimensionality, address, 4-byte
  // dimensions) and 4 (class, flags, dimensionality, the dimensions' byte width, dimensions).
  const auto fail = [&](const std::string& problem) {
    throwAtByte(path_, at, "data layout of " + what + ": " + problem);
  };
  if (size < 2) fail("truncated");
  const int version = m[0];
  size_t pos = 0;
  int rank = 0;
  int width = 4;
  if (version == 1 || version == 2) {
    if (size < 3 || m[2] != kChunkedLayout) return;
    rank = m[1];
    pos = 8 + static_cast<size_t>(offset_bytes_);
  } else if (version == 3) {
    if (m[1] != kChunkedLayout) return;
    if (size < 3) fail("truncated");
    rank = m[2];
    pos = 3 + static_cast<size_t>(offset_bytes_);
  } else if (version == 4) {
    if (m[1] != kChunkedLayout) return;
    if (size < 5) fail("truncated");
    rank = m[3];
    width = m[4];
    pos = 5;
    if (width < 1 || width > 8) fail("dimensions " + std::to_string(width) + " bytes wide");
  } else {
    fail("unknown version " + std::to_string(version));
  }
  // One more dimension than the dataspace has (the element size); a chunked dataspace has one.
  if (rank < 2 || rank > 33) fail("dimensionality " + std::to_string(rank));
  if (pos + static_cast<size_t>(rank) * static_cast<size_t>(width) > size) fail("truncated");
  // The last "dimension" is the element size: the product is a chunk's bytes, which the library
  // allocates to read one.
  uint64_t bytes = 1;
  for (int d = 0; d < rank; ++d) {
    const uint64_t n = loadLe(m + pos + static_cast<size_t>(d * width), width);
    if (n == 0) fail("a chunk dimension of 0");
    if (n > kMaxHdf5ChunkBytes || bytes * n > kMaxHdf5ChunkBytes)
      fail("chunks of more than " + std::to_string(kMaxHdf5ChunkBytes) + " bytes");
    bytes *= n;
  }
  if (version <= 3) {
    const size_t address_at = version == 3 ? 3 : 8;
    checkChunkIndex(loadLe(m + address_at, offset_bytes_), at + static_cast<int64_t>(address_at),
                    rank, filtered ? 0 : bytes, what);
  }
}

void Hdf5Precheck::checkChunkIndex(uint64_t address, int64_t cited, int rank,
                                   uint64_t unfiltered_bytes, const std::string& what) const {
  // A chunk B-tree's keys hold the chunk's stored size (4 bytes), its filter mask (4) and `rank`
  // 8-byte offsets; its leaves' children are the chunks, which the library reads at their stored
  // size. Without filters libhdf5 1.10.8 then copies the chunk's bytes out of that buffer, so such
  // a chunk must store exactly `unfiltered_bytes` (a 1,016-byte chunk was read as 2,400, a heap
  // overflow inside H5Dread, found by fuzzing). What a filtered chunk decodes to is checked where
  // evkit decodes it (hdf5_filters.h).
  if (undefinedAddress(address, offset_bytes_)) return;  // no chunk written yet
  const std::string index = "chunk index of " + what;
  checkBTree(address, cited, kChunkNodes, 8 + 8 * static_cast<size_t>(rank), index,
             [&](const uint8_t* key, uint64_t chunk, int64_t at) {
               const uint64_t stored = loadLe(key, 4);
               if (!spans(chunk, stored) || stored > kMaxHdf5ChunkBytes) {
                 throwAtByte(path_, at,
                             index + ": a chunk of " + std::to_string(stored) +
                                 " bytes at address " + std::to_string(chunk) +
                                 " runs past the end of the file");
               }
               if (unfiltered_bytes != 0 && stored != unfiltered_bytes) {
                 throwAtByte(path_, at,
                             index + ": a chunk of " + std::to_string(stored) +
                                 " bytes stored without filters, for " +
                                 std::to_string(unfiltered_bytes) + " bytes");
               }
             });
}

void Hdf5Precheck::checkGroupIndex(uint64_t address, int64_t cited, const std::string& what) const {
  // An old-style group's B-tree: its keys are offsets into the group's local heap (L bytes), its
  // leaves' children symbol table nodes ("SNOD", version, reserved, the symbols' count, then the
  // entries; section III.B). libhdf5 1.10.8 reads a node at any address it is given, the
  // undefined one included (a segfault inside H5Lexists, found by fuzzing).
  const std::string index = "group index of " + what;
  checkBTree(address, cited, kGroupNodes, static_cast<size_t>(length_bytes_), index,
             [&](const uint8_t*, uint64_t node, int64_t at) {
               if (!spans(node, 8))
                 throwAtByte(path_, at, index + ": a symbol table node past the end of the file");
             });
}

void Hdf5Precheck::checkBTree(
    uint64_t address, int64_t cited, int type, size_t key, const std::string& index,
    const std::function<void(const uint8_t* key, uint64_t child, int64_t at)>& leaf) const {
  // Version 1 B-tree (section III.A.1): "TREE", type, level, entries, two sibling addresses, then
  // key, child, key, child, ..., key. Every node and child lies inside the file; `leaf` checks
  // what a leaf's children point at.
  const auto fail = [&](int64_t at, const std::string& problem) {
    throwAtByte(path_, at, index + ": " + problem);
  };
  const size_t header = 8 + 2 * static_cast<size_t>(offset_bytes_);
  const size_t entry = key + static_cast<size_t>(offset_bytes_);
  // Each node's address with where it was read (the message, or the parent node).
  std::vector<std::pair<uint64_t, int64_t>> pending = {{address, cited}};
  std::set<uint64_t> seen = {address};
  std::vector<uint8_t> node;
  while (!pending.empty()) {
    const auto [node_address, parent] = pending.back();
    pending.pop_back();
    if (!spans(node_address, header)) {
      fail(parent, "a node at address " + std::to_string(node_address) + " outside the file");
    }
    const int64_t at = static_cast<int64_t>(base_ + node_address);
    node.resize(header);
    file_.seek(at);
    file_.readExact(node.data(), header, "a B-tree node");
    if (std::memcmp(node.data(), "TREE", 4) != 0 || node[4] != type)
      fail(at, "not a B-tree node of type " + std::to_string(type));
    const int level = node[5];
    const uint64_t entries = loadLe(&node[6], 2);
    const uint64_t bytes = header + entries * entry + key;
    if (!spans(node_address, bytes))
      fail(at, std::to_string(entries) + " entries run past the end of the file");
    node.resize(bytes);
    file_.readExact(node.data() + header, bytes - header, "B-tree node entries");
    for (uint64_t i = 0; i < entries; ++i) {
      const uint8_t* k = &node[header + i * entry];
      const uint64_t child = loadLe(k + key, offset_bytes_);
      if (!spans(child, 1)) fail(at, "a child address outside the file");
      if (level == 0) {
        leaf(k, child, at);
      } else {
        if (seen.size() > kMaxIndexNodes)
          fail(at, "more than " + std::to_string(kMaxIndexNodes) + " nodes");
        if (seen.insert(child).second) pending.push_back({child, at});
      }
    }
  }
}

void Hdf5Precheck::checkAttribute(const uint8_t* m, uint64_t size, int64_t at,
                                  const std::string& what) const {
  // Attribute message, section IV.A.2.m: version, flags, name, datatype and dataspace sizes
  // (2 bytes each), [v3: name encoding], then the three, each padded to 8 bytes in version 1, then
  // the value. libhdf5 1.10.8 copies the value at the size the datatype and dataspace give, past
  // the message when they claim more (a heap overflow inside H5Aexists, found by fuzzing).
  const auto fail = [&](const std::string& problem) {
    throwAtByte(path_, at, "an attribute of " + what + ": " + problem);
  };
  if (size < 8) fail("truncated");
  const int version = m[0];
  if (version < 1 || version > 3) fail("unknown version " + std::to_string(version));
  const auto padded = [&](uint64_t n) { return version == 1 ? (n + 7) / 8 * 8 : n; };
  const uint64_t name = loadLe(m + 2, 2), type = loadLe(m + 4, 2), space = loadLe(m + 6, 2);
  const uint64_t type_at = (version == 3 ? 9 : 8) + padded(name);
  const uint64_t space_at = type_at + padded(type);
  const uint64_t value_at = space_at + padded(space);
  if (value_at > size || type < 8 || space < 4) fail("its parts run past the message");
  if (version >= 2 && (m[1] & 0x01) != 0) fail(kSharedDatatype);
  checkDatatype(m + type_at, type, at + static_cast<int64_t>(type_at), "an attribute of " + what);
  if ((m[type_at] & 0x0f) == kVariableLength) return;  // the value holds heap references
  // A null dataspace (v2 type 2) holds no value; a scalar one (rank 0) one element.
  if (m[space_at] >= 2 && m[space_at + 3] == 2) return;
  const std::optional<uint64_t> elements =
      m[space_at + 1] > 32 ? std::nullopt : dataspaceElements(m + space_at, space);
  if (!elements) fail("a damaged dataspace");
  const uint64_t element_bytes = loadLe(m + type_at + 4, 4);
  if (*elements != 0 && element_bytes > (size - value_at) / *elements)
    fail("a value larger than its message");
}

uint64_t Hdf5Precheck::checkDatatype(const uint8_t* m, uint64_t size, int64_t at,
                                     const std::string& what, int depth) const {
  // Datatype message, section IV.A.2.d: class and version, 3 bytes of class bits, the element size
  // (4 bytes), then the class's properties. Returns the bytes the encoding takes.
  //
  // Numbers: their bits' offset and precision (2 bytes each), a float's exponent and mantissa
  // locations and sizes (1 byte each) and the exponent's bias (4). libhdf5 converts numbers of any
  // stated size and precision, reading past its buffers for sizes no machine has (integers of
  // 12,802 and of 16 bytes) and for bits past the element's (a precision of 32,832 bits in an
  // 8-byte integer), all found by fuzzing. Event files hold numbers of 1 to 8 bytes.
  //
  // Enumerations, compounds, arrays and variable-length types hold other datatypes, and names that
  // libhdf5 reads to their NUL: an enumeration (h5py's bool) allocates its values at its base
  // type's size times its members (an 8 GB request from a base type of 2^32 - 2^16 + 1 bytes,
  // found by fuzzing), so every datatype within is checked as a number is, and every name and
  // value must lie inside the message.
  const auto fail = [&](const std::string& problem) {
    throwAtByte(path_, at, "datatype of " + what + ": " + problem);
  };
  if (depth > kMaxTypeDepth) fail("datatypes nested deeper than " + std::to_string(kMaxTypeDepth));
  if (size < 8) fail("truncated");
  const int type_class = m[0] & 0x0f, version = m[0] >> 4;
  const uint64_t bits = loadLe(m + 1, 3), bytes = loadLe(m + 4, 4);
  if (version < 1 || version > 4) fail("unknown version " + std::to_string(version));
  // A name ending with its NUL inside the message, from `pos`; returns the bytes it takes (padded
  // to 8 before version 3).
  const auto name = [&](uint64_t pos) -> uint64_t {
    const void* nul = pos < size ? std::memchr(m + pos, 0, size - pos) : nullptr;
    if (nul == nullptr) fail("a name that runs past the message");
    const uint64_t length = static_cast<uint64_t>(static_cast<const uint8_t*>(nul) - (m + pos));
    return version >= 3 ? length + 1 : (length + 8) / 8 * 8;
  };
  const auto inner = [&](uint64_t pos) -> uint64_t {  // a datatype within, from `pos`
    if (pos > size) fail("truncated properties");
    return pos +
           checkDatatype(m + pos, size - pos, at + static_cast<int64_t>(pos), what, depth + 1);
  };
  switch (type_class) {
    case 0:    // fixed-point
    case 1:    // floating-point
    case 4: {  // bit field
      if (bytes != 1 && bytes != 2 && bytes != 4 && bytes != 8)
        fail("a number of " + std::to_string(bytes) + " bytes");
      const uint64_t used = type_class == 1 ? 20 : 12;
      if (size < used) fail("truncated properties");
      const uint64_t offset = loadLe(m + 8, 2), precision = loadLe(m + 10, 2);
      if (precision == 0 || offset + precision > 8 * bytes) {
        fail("bits " + std::to_string(offset) + " to " + std::to_string(offset + precision) +
             " of a " + std::to_string(8 * bytes) + "-bit number");
      }
      if (type_class == 1 && (m[12] + m[13] > precision || m[14] + m[15] > precision))
        fail("an exponent or mantissa past the number's precision");
      return used;
    }
    case 2:  // time: its precision
      if (size < 10) fail("truncated properties");
      return 10;
    case 3:  // string
    case 7:  // reference
      return 8;
    case 5: {  // opaque: an ASCII tag of the length the class bits give
      const uint64_t tag = bits & 0xff;
      if (tag > size - 8) fail("an opaque tag that runs past the message");
      return 8 + tag;
    }
    case 6: {  // compound: each member's name, byte offset, [version 1: array dimensions], type
      const uint64_t members = bits & 0xffff;
      const int offset_bytes = bytes < (1u << 8)    ? 1
                               : bytes < (1u << 16) ? 2
                               : bytes < (1u << 24) ? 3
                                                    : 4;
      uint64_t pos = 8;
      for (uint64_t i = 0; i < members; ++i) {
        pos += name(pos);
        pos += version >= 3 ? offset_bytes : 4;
        if (version == 1) pos += 28;  // rank, reserved, permutation, reserved, four dimensions
        pos = inner(pos);
      }
      return pos;
    }
    case 8: {  // enumeration: the base type (an integer of the enumeration's size), names, values
      const uint64_t members = bits & 0xffff;
      uint64_t pos = inner(8);
      if ((m[8] & 0x0f) != 0 || loadLe(m + 12, 4) != bytes)
        fail("an enumeration whose base type is not an integer of its size");
      for (uint64_t i = 0; i < members; ++i) pos += name(pos);
      if (pos > size || members * bytes > size - pos) fail("enumeration values past the message");
      return pos + members * bytes;
    }
    case 9:  // variable-length: the base type
      return inner(8);
    case 10: {  // array: rank, [version 2: 3 reserved bytes], dimensions, [permutation], base type
      if (size < 9) fail("truncated properties");
      const uint64_t rank = m[8];
      if (rank == 0 || rank > 32) fail("an array of rank " + std::to_string(rank));
      const uint64_t dims_at = version >= 3 ? 9 : 12;
      const uint64_t base_at = dims_at + rank * (version >= 3 ? 4 : 8);
      if (base_at > size) fail("truncated properties");
      uint64_t elements = 1;
      for (uint64_t d = 0; d < rank; ++d) {
        if (__builtin_mul_overflow(elements, loadLe(m + dims_at + 4 * d, 4), &elements) ||
            elements > (uint64_t{1} << 32))
          fail("an array of more than 2^32 elements");
      }
      const uint64_t end = inner(base_at);
      uint64_t array_bytes = 0;
      if (__builtin_mul_overflow(loadLe(m + base_at + 4, 4), elements, &array_bytes) ||
          array_bytes != bytes)
        fail("an array whose size is not its elements'");
      return end;
    }
    default:
      fail("unknown class " + std::to_string(type_class));
  }
  return size;  // not reached: fail throws
}

}  // namespace evkit::detail
