#include "core/train/distributed.h"

#include <cmath>
#include <sstream>

#include <torch/csrc/distributed/c10d/FileStore.hpp>
#include <torch/csrc/distributed/c10d/ProcessGroup.hpp>
#include <torch/csrc/distributed/c10d/TCPStore.hpp>
#ifdef USE_C10D_GLOO
#include <torch/csrc/distributed/c10d/ProcessGroupGloo.hpp>
#endif
#ifdef USE_C10D_NCCL
#include <torch/csrc/distributed/c10d/ProcessGroupNCCL.hpp>
#endif

#include "core/util/error.h"

namespace avatar::train {

namespace {

// Gradients travel in buckets of at most this many elements (64 MB of float32).
constexpr int64_t kBucketElements = int64_t{16} << 20;

// An exception's message without c10's backtrace.
std::string Describe(const std::exception& e) {
  if (const auto* c10 = dynamic_cast<const c10::Error*>(&e)) return c10->what_without_backtrace();
  return e.what();
}

std::chrono::milliseconds Millis(double seconds) {
  return std::chrono::milliseconds(static_cast<int64_t>(std::llround(seconds * 1000.0)));
}

}  // namespace

bool HaveNccl() {
#ifdef USE_C10D_NCCL
  return true;
#else
  return false;
#endif
}

InitMethod ParseInitUrl(const std::string& url) {
  InitMethod m;
  const std::string file = "file://", tcp = "tcp://";
  if (url.rfind(file, 0) == 0) {
    m.scheme = "file";
    m.path = url.substr(file.size());
    AVATAR_CHECK_OPTION(!m.path.empty() && m.path[0] == '/')
        << "--init '" << url << "': a file rendezvous is file:///ABSOLUTE/PATH";
    AVATAR_CHECK_OPTION(m.path.back() != '/') << "--init '" << url << "': names a folder, not a file";
    return m;
  }
  if (url.rfind(tcp, 0) == 0) {
    m.scheme = "tcp";
    const std::string rest = url.substr(tcp.size());
    const size_t colon = rest.rfind(':');
    AVATAR_CHECK_OPTION(colon != std::string::npos && colon > 0 && colon + 1 < rest.size())
        << "--init '" << url << "': a TCP rendezvous is tcp://HOST:PORT";
    m.host = rest.substr(0, colon);
    if (m.host.size() >= 2 && m.host.front() == '[' && m.host.back() == ']')
      m.host = m.host.substr(1, m.host.size() - 2);
    const std::string port = rest.substr(colon + 1);
    AVATAR_CHECK_OPTION(port.find_first_not_of("0123456789") == std::string::npos && port.size() <= 5)
        << "--init '" << url << "': port '" << port << "' is not a number";
    m.port = std::stoi(port);
    AVATAR_CHECK_OPTION(m.port >= 1 && m.port <= 65535) << "--init '" << url << "': port must be in 1..65535";
    AVATAR_CHECK_OPTION(m.host.find('/') == std::string::npos) << "--init '" << url << "': malformed host";
    return m;
  }
  throw InvalidOptions("--init '" + url + "': the rendezvous is file:///PATH or tcp://HOST:PORT");
}

void DistributedOptions::Validate() const {
  AVATAR_CHECK_OPTION(world_size >= 1) << "--world-size must be >= 1";
  AVATAR_CHECK_OPTION(rank >= 0 && rank < world_size)
      << "--rank " << rank << " is out of range for --world-size " << world_size << " (0.." << world_size - 1 << ")";
  AVATAR_CHECK_OPTION(backend == "gloo" || backend == "nccl")
      << "--backend must be gloo or nccl, not '" << backend << "'";
  AVATAR_CHECK_OPTION(timeout_s > 0 && std::isfinite(timeout_s)) << "--dist-timeout must be > 0 seconds";
  if (!enabled()) return;
  AVATAR_CHECK_OPTION(!init.empty()) << "--world-size " << world_size
                                     << " needs --init file:///PATH or tcp://HOST:PORT";
  (void)ParseInitUrl(init);
  AVATAR_CHECK_OPTION(backend != "nccl" || HaveNccl())
      << "--backend nccl: this LibTorch build has no NCCL backend (it comes with CUDA builds); use --backend gloo";
}

struct ProcessGroupReducer::Impl {
  c10::intrusive_ptr<c10d::Store> store;
  c10::intrusive_ptr<c10d::ProcessGroup> group;
  // Where the collectives' tensors live: the CPU for Gloo, the GPU for NCCL.
  torch::Device device{torch::kCPU};
  std::string where;  // for messages: "rank R of W (INIT)"

  // Runs one collective to its end; a failure (a rank gone, the timeout) becomes Io.
  void Wait(const c10::intrusive_ptr<c10d::Work>& work, const char* what) {
    try {
      work->wait();
    } catch (const std::exception& e) {
      throw Io("data-parallel training, " + where + ": " + what +
               " failed (another rank stopped or is unreachable): " + Describe(e));
    }
  }
  void AllReduce(torch::Tensor& t, c10d::ReduceOp op, const char* what) {
    std::vector<at::Tensor> tensors = {t};
    c10d::AllreduceOptions o;
    o.reduceOp = op;
    c10::intrusive_ptr<c10d::Work> work;
    try {
      work = group->allreduce(tensors, o);
    } catch (const std::exception& e) {
      throw Io("data-parallel training, " + where + ": " + what + " failed: " + Describe(e));
    }
    Wait(work, what);
  }
};

ProcessGroupReducer::ProcessGroupReducer(const DistributedOptions& options)
    : options_(options), impl_(std::make_unique<Impl>()) {
  options_.Validate();
  AVATAR_CHECK_OPTION(!options_.init.empty()) << "data-parallel training needs --init file:///PATH or tcp://HOST:PORT";
  const InitMethod init = ParseInitUrl(options_.init);
  const auto timeout = Millis(options_.timeout_s);
  const int rank = static_cast<int>(options_.rank), world = static_cast<int>(options_.world_size);
  impl_->where = "rank " + std::to_string(rank) + " of " + std::to_string(world) + " (" + options_.init + ")";
  std::ostringstream timeout_text;
  timeout_text << options_.timeout_s;
  try {
    if (init.scheme == "file") {
      impl_->store = c10::make_intrusive<c10d::FileStore>(init.path, world);
    } else {
      c10d::TCPStoreOptions o;
      o.port = static_cast<std::uint16_t>(init.port);
      o.isServer = rank == 0;
      o.numWorkers = static_cast<size_t>(world);
      o.waitWorkers = true;
      o.timeout = timeout;
      impl_->store = c10::make_intrusive<c10d::TCPStore>(init.host, o);
    }
    impl_->store->setTimeout(timeout);
    if (options_.backend == "gloo") {
#ifdef USE_C10D_GLOO
      auto o = c10d::ProcessGroupGloo::Options::create(timeout);
      // The address the other ranks reach this one at: loopback for a file rendezvous (one
      // machine), this host's name for TCP.
      o->devices.push_back(init.scheme == "file" ? c10d::ProcessGroupGloo::createDeviceForHostname("127.0.0.1")
                                                 : c10d::ProcessGroupGloo::createDefaultDevice());
      impl_->group = c10::make_intrusive<c10d::ProcessGroupGloo>(impl_->store, rank, world, o);
#else
      throw InvalidOptions("--backend gloo: this build has no c10d Gloo backend");
#endif
    } else {
#ifdef USE_C10D_NCCL
      impl_->device = torch::Device(torch::kCUDA);
      impl_->group = c10::make_intrusive<c10d::ProcessGroupNCCL>(impl_->store, rank, world,
                                                                 c10d::ProcessGroupNCCL::Options::create());
#else
      throw InvalidOptions("--backend nccl: this LibTorch build has no NCCL backend; use --backend gloo");
#endif
    }
  } catch (const Error&) {
    throw;
  } catch (const std::exception& e) {
    throw Io("data-parallel training, " + impl_->where + ": could not join the group within " + timeout_text.str() +
             " s (are all " + std::to_string(world) +
             " ranks started with the same --init? a file rendezvous must "
             "not exist before the run: delete a stale one): " +
             Describe(e));
  }
  // Every rank has joined once one collective went through.
  Barrier();
}

ProcessGroupReducer::~ProcessGroupReducer() = default;

void ProcessGroupReducer::Barrier() {
  torch::Tensor t = torch::zeros({1}, torch::TensorOptions().dtype(torch::kFloat64).device(impl_->device));
  impl_->AllReduce(t, c10d::ReduceOp::SUM, "joining");
}

bool ProcessGroupReducer::ReduceGradients(const std::vector<torch::Tensor>& params, bool local_ok,
                                          std::vector<double>& values) {
  torch::NoGradGuard no_grad;
  const int64_t n = static_cast<int64_t>(params.size()), nv = static_cast<int64_t>(values.size());
  // Header: [ranks not ok, ranks with each gradient..., values...], summed.
  torch::Tensor header = torch::zeros({1 + n + nv}, torch::kFloat64);
  auto h = header.accessor<double, 1>();
  h[0] = local_ok ? 0.0 : 1.0;
  for (int64_t i = 0; i < n; ++i) h[1 + i] = params[i].grad().defined() ? 1.0 : 0.0;
  for (int64_t i = 0; i < nv; ++i) h[1 + n + i] = values[i];
  torch::Tensor reduced = header.to(impl_->device);
  impl_->AllReduce(reduced, c10d::ReduceOp::SUM, "reducing the step's flags");
  header = reduced.to(torch::kCPU).contiguous();
  h = header.accessor<double, 1>();
  const double w = static_cast<double>(options_.world_size);
  for (int64_t i = 0; i < nv; ++i) values[i] = h[1 + n + i] / w;
  const bool all_ok = h[0] == 0.0;

  // Gradients that some rank has, bucketed by dtype and device; a rank without one adds zeros.
  std::vector<int64_t> bucket;
  int64_t bucket_elements = 0;
  auto flush = [&] {
    if (bucket.empty()) return;
    std::vector<torch::Tensor> flat;
    for (int64_t i : bucket) {
      const torch::Tensor& g = params[i].grad();
      flat.push_back(g.defined() ? g.reshape({-1}) : torch::zeros({params[i].numel()}, params[i].options()));
    }
    const torch::Device grad_device = params[bucket[0]].device();
    torch::Tensor buffer = torch::cat(flat).to(impl_->device);
    impl_->AllReduce(buffer, c10d::ReduceOp::SUM, "reducing the gradients");
    buffer = buffer.div_(w).to(grad_device);
    int64_t offset = 0;
    for (int64_t i : bucket) {
      const torch::Tensor& p = params[i];
      torch::Tensor mean = buffer.narrow(0, offset, p.numel()).view(p.sizes());
      offset += p.numel();
      if (p.grad().defined())
        p.mutable_grad().copy_(mean);
      else
        p.mutable_grad() = mean.clone();
    }
    bucket.clear();
    bucket_elements = 0;
  };
  for (int64_t i = 0; i < n; ++i) {
    if (h[1 + i] == 0.0) continue;
    const torch::Tensor& p = params[i];
    if (!bucket.empty()) {
      const torch::Tensor& first = params[bucket[0]];
      if (first.scalar_type() != p.scalar_type() || first.device() != p.device() ||
          bucket_elements + p.numel() > kBucketElements)
        flush();
    }
    bucket.push_back(i);
    bucket_elements += p.numel();
  }
  flush();
  return all_ok;
}

void ProcessGroupReducer::Broadcast(const std::vector<torch::Tensor>& tensors) {
  torch::NoGradGuard no_grad;
  for (const torch::Tensor& t : tensors) {
    if (!t.defined() || t.numel() == 0) continue;
    torch::Tensor buffer = t.detach().contiguous().to(impl_->device);
    std::vector<at::Tensor> list = {buffer};
    c10::intrusive_ptr<c10d::Work> work;
    try {
      work = impl_->group->broadcast(list, c10d::BroadcastOptions());
    } catch (const std::exception& e) {
      throw Io("data-parallel training, " + impl_->where + ": broadcasting rank 0's weights failed: " + Describe(e));
    }
    impl_->Wait(work, "broadcasting rank 0's weights");
    if (!buffer.is_same(t)) t.detach().copy_(buffer);
  }
}

void ProcessGroupReducer::AllMax(std::vector<double>& values) {
  if (values.empty()) return;
  torch::Tensor t = torch::tensor(values, torch::kFloat64).to(impl_->device);
  impl_->AllReduce(t, c10d::ReduceOp::MAX, "agreeing across ranks");
  t = t.to(torch::kCPU).contiguous();
  for (size_t i = 0; i < values.size(); ++i) values[i] = t[static_cast<int64_t>(i)].item<double>();
}

TrainBatch SliceBatch(const TrainBatch& b, int64_t start, int64_t count) {
  return b.Map([&](const torch::Tensor& t) { return t.narrow(0, start, count); });
}

ShardedBatchSource::ShardedBatchSource(BatchSource& inner, int64_t rank, int64_t world_size)
    : inner_(inner), rank_(rank), world_(world_size) {
  AVATAR_CHECK_OPTION(world_ >= 1 && rank_ >= 0 && rank_ < world_) << "ShardedBatchSource: rank out of range";
}

TrainBatch ShardedBatchSource::Next() {
  const TrainBatch b = inner_.Next();
  const int64_t total = b.size();
  AVATAR_CHECK_INPUT(total % world_ == 0 && total > 0)
      << "data-parallel training: a batch of " << total << " pairs does not divide among " << world_ << " ranks";
  const int64_t each = total / world_;
  return SliceBatch(b, rank_ * each, each);
}

}  // namespace avatar::train
