// Steady state of the full-motion warm start: once a stream runs, the motion
// warp (its scratch buffers) and the stream's copy of each frame's depth
// perform no heap allocation (counted by replacing operator new).
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <cstdlib>
#include <functional>
#include <new>

#include "allocation_counter.h"
#include "normal_fusion/stream_fuser.h"
#include "normal_fusion/warp_motion.h"
#include "test_util.h"

namespace normal_fusion {
namespace {

using test::allocationsDuring;

TEST(AllocationsMotion, NonePerFrameOfAStreamWarpedByMotion) {
  NormalMap gt;
  FusionProblem problem = test::cylinderScene(96, 64, &gt);
  NormalInput input;
  input.normals = test::noisy(gt, 0.3, 5);
  problem.inputs.push_back(input);
  const ScalarMap depth_m(96, 64, 1, 2.0f);
  StreamSettings settings;
  settings.solver.max_total_inner_iterations = 20;
  settings.solver.num_threads = 2;
  StreamFuser fuser(settings);
  std::int64_t stamp_ns = 0;
  StreamResult result;
  // 1 cm to the side per frame, alternating in sign.
  auto frame = [&](int k) {
    Pose T;
    T.t[0] = k % 2 == 0 ? 0.01 : -0.01;
    stamp_ns += 33000000;
    fuser.fuse(stamp_ns, problem,
               k == 0 ? FrameRotation::still() : FrameRotation::knownMotion(T),
               std::chrono::steady_clock::now(), &result, &depth_m);
    fuser.endFrame(0.0);
  };
  for (int k = 0; k < 3; ++k) frame(k);
  ASSERT_TRUE(result.motion_warped);
  const long count = allocationsDuring([&] {
    for (int k = 3; k < 6; ++k) frame(k);
  });
  EXPECT_TRUE(result.motion_warped);
  EXPECT_EQ(count, 0);
  // The counter works: a warp into new scratch buffers allocates.
  SolverState state = fuser.state();
  EXPECT_GT(allocationsDuring([&] {
              MotionWarpScratch scratch;
              warpStateByMotion(state, depth_m, problem.K, Pose(), scratch, 2);
            }),
            0);
}

}  // namespace
}  // namespace normal_fusion
