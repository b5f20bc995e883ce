#include "core/model/checkpoint.h"

#include <cstdio>
#include <cstring>

#include "core/io/atomic_file.h"
#include "core/util/error.h"

namespace avatar {

namespace {

constexpr char kMagic[8] = {'A', 'V', 'S', 'T', 'A', 'R', 'C', 'H'};

uint64_t Fnv1a(const char* data, size_t n) {
  uint64_t h = 1469598103934665603ULL;
  for (size_t i = 0; i < n; ++i) {
    h ^= static_cast<unsigned char>(data[i]);
    h *= 1099511628211ULL;
  }
  return h;
}

template <typename T>
void Put(std::string& out, T value) {
  char buf[sizeof(T)];
  std::memcpy(buf, &value, sizeof(T));
  out.append(buf, sizeof(T));
}

std::string DtypeName(torch::ScalarType t) {
  switch (t) {
    case torch::kFloat32:
      return "float32";
    case torch::kFloat64:
      return "float64";
    case torch::kFloat16:
      return "float16";
    case torch::kInt64:
      return "int64";
    case torch::kInt32:
      return "int32";
    case torch::kUInt8:
      return "uint8";
    case torch::kBool:
      return "bool";
    default:
      throw InvalidInput(std::string("tensor archives cannot store dtype ") + c10::toString(t));
  }
}

bool DtypeFromName(const std::string& name, torch::ScalarType* t) {
  if (name == "float32")
    *t = torch::kFloat32;
  else if (name == "float64")
    *t = torch::kFloat64;
  else if (name == "float16")
    *t = torch::kFloat16;
  else if (name == "int64")
    *t = torch::kInt64;
  else if (name == "int32")
    *t = torch::kInt32;
  else if (name == "uint8")
    *t = torch::kUInt8;
  else if (name == "bool")
    *t = torch::kBool;
  else
    return false;
  return true;
}

}  // namespace

const torch::Tensor& TensorArchive::Get(const std::string& name, const std::string& file) const {
  for (const auto& [n, t] : tensors) {
    if (n == name) return t;
  }
  throw ModelLoad((file.empty() ? std::string("archive") : file) + ": tensor '" + name +
                  "' is missing (the file is incomplete or from another version)");
}

std::string EncodeTensorArchive(const TensorArchive& archive) {
  nlohmann::json header = {{"kind", archive.kind}, {"meta", archive.meta}, {"tensors", nlohmann::json::array()}};
  std::string data;
  std::vector<torch::Tensor> cpu;
  for (const auto& [name, tensor] : archive.tensors) {
    torch::Tensor t = tensor.detach().to(torch::kCPU).contiguous();
    const size_t nbytes = t.numel() * t.element_size();
    header["tensors"].push_back({{"name", name},
                                 {"dtype", DtypeName(t.scalar_type())},
                                 {"shape", t.sizes().vec()},
                                 {"offset", data.size()},
                                 {"nbytes", nbytes}});
    data.append(static_cast<const char*>(t.data_ptr()), nbytes);
  }
  const std::string header_text = header.dump();
  std::string out(kMagic, sizeof(kMagic));
  Put<uint32_t>(out, kArchiveVersion);
  Put<uint64_t>(out, header_text.size());
  out += header_text;
  Put<uint64_t>(out, data.size());
  out += data;
  Put<uint64_t>(out, Fnv1a(out.data(), out.size()));
  return out;
}

TensorArchive DecodeTensorArchive(const std::string& bytes, const std::string& source) {
  const auto fail = [&](const std::string& why) { return ModelLoad(source + ": " + why); };
  size_t pos = 0;
  const auto take = [&](void* dst, size_t n, const char* what) {
    if (bytes.size() - pos < n || pos > bytes.size())
      throw fail(std::string("file is truncated (while reading ") + what + ")");
    std::memcpy(dst, bytes.data() + pos, n);
    pos += n;
  };
  char magic[8];
  if (bytes.size() < sizeof(magic) || std::memcmp(bytes.data(), kMagic, sizeof(magic)) != 0) {
    throw fail("not an Avatar Studio model/avatar file (bad magic bytes)");
  }
  take(magic, sizeof(magic), "magic");
  uint32_t version = 0;
  take(&version, sizeof(version), "version");
  if (version != kArchiveVersion) {
    throw fail("format version " + std::to_string(version) + " is not supported (this build reads version " +
               std::to_string(kArchiveVersion) + ")");
  }
  uint64_t header_len = 0;
  take(&header_len, sizeof(header_len), "header length");
  if (header_len > bytes.size() - pos) throw fail("file is truncated (header)");
  const std::string header_text = bytes.substr(pos, header_len);
  pos += header_len;
  uint64_t data_len = 0;
  take(&data_len, sizeof(data_len), "data length");
  if (data_len > bytes.size() - pos || bytes.size() - pos - data_len < sizeof(uint64_t)) {
    throw fail("file is truncated (tensor data: " + std::to_string(bytes.size() - pos) + " bytes left, " +
               std::to_string(data_len) + " + checksum expected)");
  }
  const size_t data_pos = pos;
  pos += data_len;
  uint64_t stored = 0;
  take(&stored, sizeof(stored), "checksum");
  if (pos != bytes.size()) throw fail("unexpected " + std::to_string(bytes.size() - pos) + " bytes after the checksum");
  if (Fnv1a(bytes.data(), data_pos + data_len) != stored) throw fail("checksum mismatch (the file is corrupt)");

  nlohmann::json header;
  try {
    header = nlohmann::json::parse(header_text);
  } catch (const nlohmann::json::exception& e) {
    throw fail(std::string("header is not valid JSON: ") + e.what());
  }
  TensorArchive archive;
  try {
    archive.kind = header.at("kind").get<std::string>();
    archive.meta = header.at("meta");
    for (const auto& entry : header.at("tensors")) {
      const std::string name = entry.at("name").get<std::string>();
      torch::ScalarType dtype;
      if (!DtypeFromName(entry.at("dtype").get<std::string>(), &dtype))
        throw fail("tensor '" + name + "' has an unknown dtype");
      const std::vector<int64_t> shape = entry.at("shape").get<std::vector<int64_t>>();
      const uint64_t offset = entry.at("offset").get<uint64_t>();
      const uint64_t nbytes = entry.at("nbytes").get<uint64_t>();
      uint64_t numel = 1;
      for (int64_t d : shape) {
        if (d < 0) throw fail("tensor '" + name + "' has a negative dimension");
        numel *= static_cast<uint64_t>(d);
      }
      if (numel * c10::elementSize(dtype) != nbytes)
        throw fail("tensor '" + name + "' byte count does not match its shape");
      if (offset > data_len || nbytes > data_len - offset)
        throw fail("tensor '" + name + "' lies outside the data block");
      torch::Tensor t = torch::empty(shape, torch::TensorOptions().dtype(dtype));
      if (nbytes > 0) std::memcpy(t.data_ptr(), bytes.data() + data_pos + offset, nbytes);
      archive.tensors.emplace_back(name, t);
    }
  } catch (const nlohmann::json::exception& e) {
    throw fail(std::string("header is malformed: ") + e.what());
  }
  return archive;
}

void WriteTensorArchive(const std::filesystem::path& path, const TensorArchive& archive) {
  WriteBytesAtomically(path, EncodeTensorArchive(archive));
}

TensorArchive ReadTensorArchive(const std::filesystem::path& path, const std::string& expected_kind,
                                std::string* fingerprint) {
  const std::string bytes = ReadFileBytes(path);
  TensorArchive archive = DecodeTensorArchive(bytes, path.string());
  if (fingerprint != nullptr) {
    uint64_t sum = 0;
    std::memcpy(&sum, bytes.data() + bytes.size() - sizeof(sum), sizeof(sum));
    char hex[17];
    std::snprintf(hex, sizeof(hex), "%016llx", static_cast<unsigned long long>(sum));
    *fingerprint = hex;
  }
  if (!expected_kind.empty() && archive.kind != expected_kind) {
    throw ModelLoad(path.string() + ": this is a '" + archive.kind + "' file, expected '" + expected_kind + "'");
  }
  return archive;
}

}  // namespace avatar
