// rostest of two running nodes (part of the gtest node test_node, run by
// compare.test): the nodelet and the standalone node give the same outputs.
#include <gtest/gtest.h>
#include <ros/ros.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "node_test_util.h"

namespace {

using nf::node_test::answered;
using nf::node_test::kHeight;
using nf::node_test::kWidth;
using nf::node_test::newStamp;
using nf::node_test::NodeClient;
using nf::node_test::waitFor;

// Two nodes (the nodelet and the standalone node) fed the same frames give
// the same fused maps and statistics.
TEST(Compare, NodeletAndStandaloneNodeGiveTheSameOutputs) {
  std::string namespaces;
  if (!ros::NodeHandle("~").getParam("compare_namespaces", namespaces)) {
    GTEST_SKIP();
  }
  const std::string a = namespaces.substr(0, namespaces.find(' '));
  const std::string b = namespaces.substr(namespaces.find(' ') + 1);
  NodeClient first(a), second(b);
  first.listen(true, false, true);
  second.listen(true, false, true);
  ASSERT_TRUE(waitFor(
      [&] {
        return first.inputSubscribers() == 4 && second.inputSubscribers() == 4;
      },
      5.0));
  const auto sequence =
      nf::synthetic::renderSequence(2, kWidth, kHeight, 4, 0.3, 30.0);
  for (std::size_t k = 0; k < sequence.size(); ++k) {
    const nf::test::NoisyFrame f = nf::test::noisyFrame(sequence[k], 50 + k);
    const auto m = first.messagesFor(f, newStamp(1.0 / 30.0));
    const ros::Time stamp = m.image->header.stamp;
    ASSERT_TRUE(answered(first, m));
    ASSERT_TRUE(answered(second, m));
    ASSERT_TRUE(waitFor(
        [&] { return first.fused(stamp) && second.fused(stamp); }, 2.0));
    const auto s1 = first.stats(stamp), s2 = second.stats(stamp);
    EXPECT_EQ(s1->inner_iterations, s2->inner_iterations);
    EXPECT_EQ(s1->outer_iterations, s2->outer_iterations);
    EXPECT_EQ(s1->warm_started, s2->warm_started);
    EXPECT_NEAR(s1->final_energy, s2->final_energy,
                1e-6 * std::abs(s1->final_energy));
    const nf::NormalMap n1 = nf::test::normalsFromImage(*first.fused(stamp));
    const nf::NormalMap n2 = nf::test::normalsFromImage(*second.fused(stamp));
    double worst = 0.0;
    for (int c = 0; c < 3; ++c) {
      for (std::size_t i = 0; i < n1.pixelCount(); ++i) {
        worst = std::max(worst, static_cast<double>(
                                    std::abs(n1.plane(c)[i] - n2.plane(c)[i])));
      }
    }
    EXPECT_LT(worst, 1e-5) << "frame " << k;
  }
}

}  // namespace
