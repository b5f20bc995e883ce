#include "core/train/shard_check.h"

#include <cstdint>
#include <cstring>
#include <stdexcept>

namespace avatar::train {
namespace {

[[noreturn]] void Fail(const std::string& why) { throw std::runtime_error(why); }

std::string Hex(char op) {
  static const char* digits = "0123456789abcdef";
  const auto u = static_cast<unsigned char>(op);
  return std::string("0x") + digits[u >> 4] + digits[u & 15];
}

// Little-endian unsigned integer of `n` bytes at `at`; the caller has checked the bounds.
uint64_t Le(const char* at, int n) {
  uint64_t v = 0;
  for (int i = n - 1; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(at[i]);
  return v;
}

class Bytes {
 public:
  explicit Bytes(const std::vector<char>& b) : b_(b) {}
  size_t size() const { return b_.size(); }
  // n bytes at `pos` as a little-endian number; fails when they are not all inside the file.
  uint64_t Get(uint64_t pos, int n, const char* what) const {
    if (pos > b_.size() || static_cast<uint64_t>(n) > b_.size() - pos)
      Fail(std::string("the zip ") + what + " lies past the end of the file");
    return Le(b_.data() + pos, n);
  }

 private:
  const std::vector<char>& b_;
};

constexpr uint32_t kEndOfDirectory = 0x06054b50;
constexpr uint32_t kZip64Locator = 0x07064b50;
constexpr uint32_t kZip64End = 0x06064b50;
constexpr uint32_t kDirectoryEntry = 0x02014b50;
constexpr uint32_t kLocalHeader = 0x04034b50;
constexpr uint64_t kAll32 = 0xFFFFFFFFu;

}  // namespace

std::vector<ShardRecord> CheckShardArchive(const std::vector<char>& bytes) {
  const Bytes b(bytes);
  const size_t n = b.size();
  if (n < 22) Fail("too short for a zip archive (" + std::to_string(n) + " bytes)");
  // The end-of-directory record: the last one within its 22 bytes + a comment of up to 65535.
  size_t eocd = n;
  const size_t lowest = n - 22 > 65535 ? n - 22 - 65535 : 0;
  for (size_t pos = n - 22 + 1; pos-- > lowest;) {
    if (b.Get(pos, 4, "end record") == kEndOfDirectory) {
      eocd = pos;
      break;
    }
  }
  if (eocd == n) Fail("no zip end-of-directory record");
  uint64_t entries = b.Get(eocd + 10, 2, "end record");
  uint64_t dir_size = b.Get(eocd + 12, 4, "end record");
  uint64_t dir_offset = b.Get(eocd + 16, 4, "end record");
  if (entries == 0xFFFF || dir_size == kAll32 || dir_offset == kAll32) {
    if (eocd < 20 || b.Get(eocd - 20, 4, "zip64 locator") != kZip64Locator) Fail("zip64 locator missing");
    const uint64_t end64 = b.Get(eocd - 20 + 8, 8, "zip64 locator");
    if (b.Get(end64, 4, "zip64 end record") != kZip64End) Fail("zip64 end record missing");
    entries = b.Get(end64 + 32, 8, "zip64 end record");
    dir_size = b.Get(end64 + 40, 8, "zip64 end record");
    dir_offset = b.Get(end64 + 48, 8, "zip64 end record");
  }
  if (dir_offset > n || dir_size > n - dir_offset) Fail("the zip directory lies past the end of the file");
  if (entries > dir_size / 46) Fail("the zip directory claims " + std::to_string(entries) + " records in " +
                                    std::to_string(dir_size) + " bytes");
  std::vector<ShardRecord> records;
  records.reserve(static_cast<size_t>(entries));
  uint64_t pos = dir_offset;
  for (uint64_t i = 0; i < entries; ++i) {
    if (b.Get(pos, 4, "directory entry") != kDirectoryEntry) Fail("zip directory entry " + std::to_string(i) + " is broken");
    const uint64_t method = b.Get(pos + 10, 2, "directory entry");
    uint64_t packed = b.Get(pos + 20, 4, "directory entry");
    uint64_t size = b.Get(pos + 24, 4, "directory entry");
    const uint64_t name_len = b.Get(pos + 28, 2, "directory entry");
    const uint64_t extra_len = b.Get(pos + 30, 2, "directory entry");
    const uint64_t comment_len = b.Get(pos + 32, 2, "directory entry");
    uint64_t local = b.Get(pos + 42, 4, "directory entry");
    b.Get(pos + 46, 0, "directory entry");
    if (name_len > n - (pos + 46)) Fail("a zip record name lies past the end of the file");
    ShardRecord r;
    r.name.assign(bytes.data() + pos + 46, static_cast<size_t>(name_len));
    // Zip64 sizes: in extra field 0x0001, only those whose 32-bit field is all ones, in order.
    uint64_t extra = pos + 46 + name_len;
    const uint64_t extra_end = extra + extra_len;
    if (extra_end + comment_len > n) Fail("zip directory entry " + std::to_string(i) + " lies past the end of the file");
    while (extra + 4 <= extra_end) {
      const uint64_t id = b.Get(extra, 2, "extra field");
      const uint64_t len = b.Get(extra + 2, 2, "extra field");
      if (id == 0x0001) {
        uint64_t at = extra + 4;
        auto take = [&](uint64_t& field) {
          if (field != kAll32) return;
          if (at + 8 > extra + 4 + len) Fail("record '" + r.name + "' has a short zip64 field");
          field = b.Get(at, 8, "zip64 field");
          at += 8;
        };
        take(size);
        take(packed);
        take(local);
      }
      extra += 4 + len;
    }
    if (method != 0) Fail("record '" + r.name + "' is compressed (method " + std::to_string(method) + ")");
    if (packed != size) Fail("record '" + r.name + "' has different stored and unpacked sizes");
    if (b.Get(local, 4, "local header") != kLocalHeader) Fail("record '" + r.name + "' has no local header");
    const uint64_t data = local + 30 + b.Get(local + 26, 2, "local header") + b.Get(local + 28, 2, "local header");
    if (data > n || size > n - data)
      Fail("record '" + r.name + "' claims " + std::to_string(size) + " bytes, more than the file holds");
    r.data_offset = static_cast<size_t>(data);
    r.size = static_cast<size_t>(size);
    records.push_back(std::move(r));
    pos = extra_end + comment_len;
  }
  return records;
}

void CheckPickleLengths(const char* data, size_t size) {
  size_t pos = 0;
  auto claim = [&](char op, size_t at, uint64_t amount, const char* what) {
    const size_t left = size - pos;
    if (amount > left)
      Fail("pickle opcode " + Hex(op) + " at byte " + std::to_string(at) + " claims " + std::to_string(amount) + " " + what + ", only " +
           std::to_string(left) + " bytes follow");
  };
  auto fixed = [&](char op, size_t at, size_t n) {
    claim(op, at, n, "bytes");
    const uint64_t v = Le(data + pos, static_cast<int>(n));
    pos += n;
    return v;
  };
  auto line = [&](char op, size_t at) {
    const char* end = static_cast<const char*>(std::memchr(data + pos, '\n', size - pos));
    if (end == nullptr) Fail("pickle opcode " + Hex(op) + " at byte " + std::to_string(at) + " has no end of line");
    pos = static_cast<size_t>(end - data) + 1;
  };
  // The memo cannot hold more entries than there are opcodes, so a memo index is bounded by the size.
  auto memo = [&](char op, size_t at, uint64_t index) {
    if (index > size) claim(op, at, index, "as a memo index");
  };
  while (pos < size) {
    const size_t at = pos;
    const char op = data[pos++];
    switch (static_cast<unsigned char>(op)) {
      case '.':  // STOP: what follows is not read
        return;
      // No argument.
      case '(': case '0': case '1': case '2': case 'N': case 'R': case ']': case 'a': case 'b': case 'd':
      case '}': case 'e': case 'l': case 's': case 't': case ')': case 'u': case 'o': case 'Q':
      case 0x81: case 0x85: case 0x86: case 0x87: case 0x88: case 0x89: case 0x8f: case 0x90: case 0x91:
      case 0x92: case 0x93: case 0x94: case 0x97: case 0x98:
        break;
      // Fixed-size arguments.
      case 0x80: case 'K': case 0x82: fixed(op, at, 1); break;
      case 'M': case 0x83: fixed(op, at, 2); break;
      case 'J': case 0x84: fixed(op, at, 4); break;
      case 'G': fixed(op, at, 8); break;
      case 0x95: claim(op, at, fixed(op, at, 8), "bytes of frame"); break;  // FRAME: its opcodes follow
      case 'q': case 'h': memo(op, at, fixed(op, at, 1)); break;
      case 'r': case 'j': memo(op, at, fixed(op, at, 4)); break;
      // A length, then that many bytes.
      case 'U': case 'C': case 0x8c: case 0x8a: {
        const uint64_t len = fixed(op, at, 1);
        claim(op, at, len, "bytes");
        pos += static_cast<size_t>(len);
        break;
      }
      case 'T': case 'X': case 'B': case 0x8b: {
        const uint64_t len = fixed(op, at, 4);
        claim(op, at, len, "bytes");
        pos += static_cast<size_t>(len);
        break;
      }
      case 0x8d: case 0x8e: case 0x96: {
        const uint64_t len = fixed(op, at, 8);
        claim(op, at, len, "bytes");
        pos += static_cast<size_t>(len);
        break;
      }
      // Text arguments ended by a newline (protocol 0).
      case 'I': case 'L': case 'F': case 'S': case 'V': case 'p': case 'g': case 'P':
        line(op, at);
        break;
      case 'c': case 'i':
        line(op, at);
        line(op, at);
        break;
      default:
        Fail("unknown pickle opcode " + Hex(op) + " at byte " + std::to_string(at));
    }
  }
  Fail("the pickle ends without its STOP opcode");
}

void CheckShard(const std::vector<char>& bytes) {
  for (const ShardRecord& r : CheckShardArchive(bytes)) {
    const std::string suffix = "data.pkl";
    if (r.name.size() >= suffix.size() && r.name.compare(r.name.size() - suffix.size(), suffix.size(), suffix) == 0 &&
        r.name.find('/') == r.name.rfind('/')) {
      CheckPickleLengths(bytes.data() + r.data_offset, r.size);
    }
  }
}

}  // namespace avatar::train
