#pragma once
// Structural checks of a dataset shard (a LibTorch pickle archive: a zip of stored records
// holding data.pkl and the tensor storages) before LibTorch reads it. LibTorch 1.13 trusts the
// lengths it reads: a zip record or a pickled string that claims gigabytes makes it allocate
// them before it finds out that the file is 13 KB (found by tests/fuzz, target dataset). These
// checks bound every such length by the bytes that are really there, without allocating.

#include <cstddef>
#include <string>
#include <vector>

namespace avatar::train {

// One record of the archive's central directory.
struct ShardRecord {
  std::string name;
  size_t data_offset = 0;  // where the stored bytes start in the file
  size_t size = 0;         // stored size (= uncompressed size: shards are never compressed)
};

// Reads the zip central directory of `bytes` (zip64 sizes included) and checks that every record
// is stored uncompressed and lies inside the file. Throws std::runtime_error saying what is wrong.
std::vector<ShardRecord> CheckShardArchive(const std::vector<char>& bytes);

// Walks the opcodes of a pickle (protocols 0-5) and checks that every length or memo index an
// opcode declares fits in the bytes left. Throws std::runtime_error saying which opcode at which
// offset claims how much.
void CheckPickleLengths(const char* data, size_t size);

// Both: the archive, then its data.pkl record. Throws std::runtime_error.
void CheckShard(const std::vector<char>& bytes);

}  // namespace avatar::train
