#pragma once
// Helpers shared by the model tests.

#include <cstdlib>
#include <cstring>
#include <string>

#include <gtest/gtest.h>

#include "core/model/goha_model.h"

namespace avatar::testing {

// The image encoder of the encoder-independent model tests: AVATAR_TEST_ENCODER, else mit_b0.
// tests/model/CMakeLists.txt runs those tests (GohaModel.*, Checkpoint.*, the gradient test) a
// second time with AVATAR_TEST_ENCODER=mobilenet_v2 (pretrained, from nsfwjs).
inline std::string TestEncoder() {
  const char* e = std::getenv("AVATAR_TEST_ENCODER");
  return e != nullptr && *e != 0 ? std::string(e) : std::string("mit_b0");
}

// ModelConfig::Tiny() with TestEncoder().
inline ModelConfig TinyForTest() {
  ModelConfig c = ModelConfig::Tiny();
  c.encoder = TestEncoder();
  if (c.encoder != "mit_b0") c.name = "tiny-" + c.encoder;
  c.Validate();
  return c;
}

// Every parameter and buffer of `b` equals its namesake in `a` bit for bit (same names, shapes,
// dtypes and bytes): what a checkpoint round trip must give.
inline void ExpectBitIdenticalWeights(const GohaModel& a, const GohaModel& b) {
  const auto pa = a->named_parameters(true);
  const auto pb = b->named_parameters(true);
  ASSERT_EQ(pa.size(), pb.size());
  for (const auto& item : pa) {
    const torch::Tensor* other = pb.find(item.key());
    ASSERT_NE(other, nullptr) << item.key() << " is missing";
    ASSERT_EQ(item.value().sizes(), other->sizes()) << item.key();
    ASSERT_EQ(item.value().dtype(), other->dtype()) << item.key();
    EXPECT_EQ(std::memcmp(item.value().data_ptr(), other->data_ptr(), item.value().nbytes()), 0) << item.key();
  }
  const auto ba = a->named_buffers(true);
  const auto bb = b->named_buffers(true);
  ASSERT_EQ(ba.size(), bb.size());
  for (const auto& item : ba) {
    const torch::Tensor* other = bb.find(item.key());
    ASSERT_NE(other, nullptr) << item.key() << " is missing";
    EXPECT_TRUE(torch::equal(item.value(), *other)) << item.key();
  }
}

}  // namespace avatar::testing
