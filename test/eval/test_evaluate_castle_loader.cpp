// The loader of ViSP's Castle sequence (evaluate's castle case): depth files,
// poses, intrinsics, the model files and the ray caster on small files
// written here; then, on the real sequence when visp-images-data is
// installed, that the model rendered with the recorded pose explains the
// recorded depth map (pose convention, depth scale, depth camera offset).
#include <gtest/gtest.h>
#include <stdlib.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "eval/castle.h"
#include "eval/synthetic.h"
#include "normal_fusion/errors.h"
#include "normal_fusion/metrics.h"

namespace normal_fusion {
namespace {

namespace fs = std::filesystem;

/// A fresh directory under the system's temp directory, removed afterwards.
class CastleLoaderTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string pattern =
        (fs::temp_directory_path() / "nf_castle_XXXXXX").string();
    ASSERT_NE(mkdtemp(pattern.data()), nullptr);
    dir_ = pattern;
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }
  std::string path(const std::string& name) const {
    return (fs::path(dir_) / name).string();
  }
  void writeText(const std::string& name, const std::string& text) const {
    std::ofstream out(path(name));
    out << text;
  }
  std::string dir_;
};

void writeLe32(std::ofstream& out, std::uint32_t v) {
  for (int k = 0; k < 4; ++k) out.put(static_cast<char>((v >> (8 * k)) & 255));
}

TEST_F(CastleLoaderTest, DepthFileGivesMetresAndNaNForZero) {
  // 3 wide, 2 high; values 0 .. 5 * 1000 units.
  {
    std::ofstream out(path("d.bin"), std::ios::binary);
    writeLe32(out, 2);  // height
    writeLe32(out, 3);  // width
    for (std::uint16_t v : {0, 1000, 2000, 3000, 4000, 65535}) {
      out.put(static_cast<char>(v & 255));
      out.put(static_cast<char>(v >> 8));
    }
  }
  const ScalarMap depth = castle::readDepth(path("d.bin"), 0.001);
  ASSERT_EQ(depth.width(), 3);
  ASSERT_EQ(depth.height(), 2);
  EXPECT_TRUE(std::isnan(depth.at(0, 0, 0)));
  EXPECT_FLOAT_EQ(depth.at(0, 0, 1), 1.0f);
  EXPECT_FLOAT_EQ(depth.at(0, 0, 2), 2.0f);
  EXPECT_FLOAT_EQ(depth.at(0, 1, 0), 3.0f);
  EXPECT_FLOAT_EQ(depth.at(0, 1, 2), 65.535f);
}

TEST_F(CastleLoaderTest, TruncatedOrMissingDepthFileThrows) {
  {
    std::ofstream out(path("short.bin"), std::ios::binary);
    writeLe32(out, 4);
    writeLe32(out, 4);
    out.put(1);  // 1 of 32 bytes
  }
  EXPECT_THROW(castle::readDepth(path("short.bin")), InputError);
  EXPECT_THROW(castle::readDepth(path("absent.bin")), InputError);
}

TEST_F(CastleLoaderTest, PoseIsReadRowMajorAndCheckedForRotation) {
  // A rotation of 90 degrees about z and a translation.
  writeText("pose.txt", "0 -1 0 0.1\n1 0 0 0.2\n0 0 1 0.3\n0 0 0 1\n");
  const synthetic::Pose pose = castle::readPose(path("pose.txt"));
  EXPECT_DOUBLE_EQ(pose.R[1], -1.0);
  EXPECT_DOUBLE_EQ(pose.R[3], 1.0);
  EXPECT_DOUBLE_EQ(pose.t[0], 0.1);
  EXPECT_DOUBLE_EQ(pose.t[2], 0.3);
  writeText("scaled.txt", "2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n");
  EXPECT_THROW(castle::readPose(path("scaled.txt")), InputError);
  writeText("short.txt", "1 0 0 0\n0 1 0 0\n");
  EXPECT_THROW(castle::readPose(path("short.txt")), InputError);
}

TEST_F(CastleLoaderTest, IntrinsicsComeFromTheCameraElement) {
  writeText("cam.xml",
            "<conf><ecm><mask><size>5</size></mask></ecm><camera>\n"
            "<px>600.5</px><py>610</py><u0>319.5</u0><v0>241</v0>"
            "</camera></conf>");
  const CameraIntrinsics K = castle::readIntrinsics(path("cam.xml"));
  EXPECT_DOUBLE_EQ(K.fx(), 600.5);
  EXPECT_DOUBLE_EQ(K.fy(), 610.0);
  EXPECT_DOUBLE_EQ(K.cx(), 319.5);
  EXPECT_DOUBLE_EQ(K.cy(), 241.0);
  writeText("bad.xml", "<camera><px>0</px><py>1</py><u0>1</u0></camera>");
  EXPECT_THROW(castle::readIntrinsics(path("bad.xml")), InputError);
}

TEST_F(CastleLoaderTest, CaoFacesFollowLoadAndTheTransform) {
  fs::create_directory(path("parts"));
  writeText("parts/square.cao",
            "V1\n# points\n4\n0 0 0\n1 0 0 # corner\n1 1 0\n0 1 0\n"
            "# segments\n0\n# face segments\n0\n# face points\n1\n"
            "4 0 1 2 3 name=square\n0\n0\n");
  writeText("main.cao",
            "V1\nload(\"parts/square.cao\")\n3\n0 0 1\n1 0 1\n0 1 1\n"
            "1\n0 1\n0\n2\n3 0 1 2\n3 0 0 1\n0\n0\n");
  synthetic::Pose shift;
  shift.t = {{10, 0, 0}};
  const std::vector<castle::Face> faces =
      castle::readCaoFaces(path("main.cao"), shift);
  // The square of the loaded file, the triangle; the degenerate face dropped.
  ASSERT_EQ(faces.size(), 2u);
  ASSERT_EQ(faces[0].vertices_obj.size(), 4u);
  EXPECT_DOUBLE_EQ(faces[0].vertices_obj[1][0], 11.0);
  ASSERT_EQ(faces[1].vertices_obj.size(), 3u);
  EXPECT_DOUBLE_EQ(faces[1].vertices_obj[0][2], 1.0);
  EXPECT_DOUBLE_EQ(faces[1].vertices_obj[2][0], 10.0);
}

TEST_F(CastleLoaderTest, VrmlFacesSkipLineSetsAndCommentedPolygons) {
  writeText("m.wrl",
            "#VRML V2.0 utf8\nShape { geometry IndexedFaceSet { coord "
            "Coordinate { point [ 0 0 0, 1 0 0, 1 1 0, 0 1 0 ] }\n"
            "coordIndex [\n# 0, 1, 2, -1,\n 0, 1, 2, 3, -1 ] } }\n"
            "Shape { geometry IndexedLineSet { coord Coordinate { point "
            "[ 5 5 5, 6 6 6 ] } coordIndex [ 0, 1, -1 ] } }\n");
  const std::vector<castle::Face> faces = castle::readVrmlFaces(path("m.wrl"));
  ASSERT_EQ(faces.size(), 1u);
  EXPECT_EQ(faces[0].vertices_obj.size(), 4u);
}

TEST(CastleRender, SquareInFrontOfTheCamera) {
  // A 0.2 m square at z = 1 m, centred on the optical axis.
  castle::Face square;
  square.vertices_obj = {{{-0.1, -0.1, 1.0}},
                         {{0.1, -0.1, 1.0}},
                         {{0.1, 0.1, 1.0}},
                         {{-0.1, 0.1, 1.0}}};
  const CameraIntrinsics K(100.0, 100.0, 20.0, 20.0);
  ScalarMap depth;
  NormalMap normals;
  castle::renderModel({square}, synthetic::Pose(), K, 41, 41, &depth, &normals);
  // Inside: depth 1, normal (0, 0, -1) facing the camera; outside: NaN.
  EXPECT_NEAR(depth.at(0, 20, 20), 1.0, 1e-6);
  EXPECT_NEAR(depth.at(0, 15, 25), 1.0, 1e-6);
  EXPECT_NEAR(normals.at(2, 20, 20), -1.0, 1e-6);
  EXPECT_NEAR(normals.at(0, 20, 20), 0.0, 1e-6);
  EXPECT_TRUE(std::isnan(depth.at(0, 20, 35)));
  EXPECT_TRUE(std::isnan(normals.at(0, 5, 20)));
  // A nearer tilted face in front of part of it wins there.
  castle::Face near_face;
  near_face.vertices_obj = {{{-0.05, -0.05, 0.5}},
                            {{0.05, -0.05, 0.5}},
                            {{0.05, 0.05, 0.6}},
                            {{-0.05, 0.05, 0.6}}};
  castle::renderModel({square, near_face}, synthetic::Pose(), K, 41, 41, &depth,
                      &normals);
  EXPECT_LT(depth.at(0, 20, 20), 0.7);
  // z = 0.55 + y: the normal facing the camera is (0, 1, -1) / sqrt(2).
  EXPECT_NEAR(normals.at(1, 20, 20), std::sqrt(0.5), 1e-6);
  EXPECT_NEAR(normals.at(2, 20, 20), -std::sqrt(0.5), 1e-6);
  // Below it (ray y = 0.09 meets the tilted plane at y = 0.054, outside) the
  // square is seen again.
  EXPECT_NEAR(depth.at(0, 29, 20), 1.0, 1e-6);
}

bool sequenceAvailable() { return castle::available(); }

TEST(CastleSequence, IntrinsicsAndFilesAsDocumented) {
  if (!sequenceAvailable()) GTEST_SKIP() << "visp-images-data not installed";
  const std::string dir = castle::kDefaultDirectory;
  const CameraIntrinsics K =
      castle::readIntrinsics(dir + "/Config/chateau_depth.xml");
  EXPECT_DOUBLE_EQ(K.fx(), 700.0);
  EXPECT_DOUBLE_EQ(K.fy(), 700.0);
  EXPECT_DOUBLE_EQ(K.cx(), 320.0);
  EXPECT_DOUBLE_EQ(K.cy(), 240.0);
  const std::vector<int> frames = castle::frameNumbers(dir);
  ASSERT_FALSE(frames.empty());
  EXPECT_EQ(frames.front(), 1);
  // The depth map: 640 x 480 as the header says, the object at 0.2 - 1 m.
  const ScalarMap depth = castle::readDepth(dir + "/Depth/Depth_0001.bin");
  EXPECT_EQ(depth.width(), 640);
  EXPECT_EQ(depth.height(), 480);
  int with_depth = 0;
  for (std::size_t i = 0; i < depth.pixelCount(); ++i) {
    const float z = depth.data()[i];
    if (std::isnan(z)) continue;
    ++with_depth;
    EXPECT_GT(z, 0.2f);
    EXPECT_LT(z, 1.0f);
  }
  EXPECT_GT(with_depth, 10000);
}

/// Share of the pixels with depth where the model rendered from T_cam_obj
/// lies within 3 mm of the depth map.
double modelAgreement(const std::vector<castle::Face>& faces,
                      const synthetic::Pose& T_cam_obj,
                      const CameraIntrinsics& K, const ScalarMap& depth) {
  ScalarMap model_depth;
  NormalMap model_normals;
  castle::renderModel(faces, T_cam_obj, K, depth.width(), depth.height(),
                      &model_depth, &model_normals);
  int with_depth = 0, agreeing = 0;
  for (std::size_t i = 0; i < depth.pixelCount(); ++i) {
    if (std::isnan(depth.data()[i])) continue;
    ++with_depth;
    if (std::fabs(model_depth.data()[i] - depth.data()[i]) <= 0.003f) {
      ++agreeing;
    }
  }
  return static_cast<double>(agreeing) / with_depth;
}

TEST(CastleSequence, ModelWithTheDepthCameraPoseExplainsTheDepthMap) {
  if (!sequenceAvailable()) GTEST_SKIP() << "visp-images-data not installed";
  const std::string dir = castle::kDefaultDirectory;
  const std::vector<castle::Face> faces = castle::loadModel(dir);
  const std::vector<int> frames = castle::frameNumbers(dir);
  const int last = frames.back();
  for (int number : {frames.front(), last}) {
    char name[64];
    std::snprintf(name, sizeof(name), "/Depth/Depth_%04d.bin", number);
    const ScalarMap depth = castle::readDepth(dir + name);
    std::snprintf(name, sizeof(name), "/CameraPose/Camera_%03d.txt", number);
    const synthetic::Pose T_color_obj = castle::readPose(dir + name);
    const CameraIntrinsics K =
        castle::readIntrinsics(dir + "/Config/chateau_depth.xml");
    synthetic::Pose T_depth_obj = T_color_obj;
    T_depth_obj.t[0] += castle::kDepthFromColorXM;
    // With the 5 cm offset the model explains nearly every depth pixel;
    // from the colour camera's own pose it does not.
    EXPECT_GT(modelAgreement(faces, T_depth_obj, K, depth), 0.95)
        << "frame " << number;
    EXPECT_LT(modelAgreement(faces, T_color_obj, K, depth), 0.6)
        << "frame " << number;
  }
}

TEST(CastleSequence, GroundTruthNormalsMatchTheRecordedDepth) {
  if (!sequenceAvailable()) GTEST_SKIP() << "visp-images-data not installed";
  const std::string dir = castle::kDefaultDirectory;
  const castle::Frame frame = castle::loadFrame(dir, 1, castle::loadModel(dir));
  EXPECT_GT(frame.agreement, 0.95);
  ASSERT_EQ(frame.image.width(), frame.depth.width());
  ASSERT_EQ(frame.normals_gt.width(), frame.depth.width());
  // Cropped to the object, K shifted with the crop.
  EXPECT_LT(frame.depth.width(), 640);
  EXPECT_DOUBLE_EQ(frame.K.cx(), 320.0 - frame.crop_x);
  // Unit normals facing the camera wherever there is ground truth.
  const std::array<double, 9> K_inv = frame.K.inverse();
  int with_gt = 0;
  for (int y = 0; y < frame.depth.height(); ++y) {
    for (int x = 0; x < frame.depth.width(); ++x) {
      const float n[3] = {frame.normals_gt.at(0, y, x),
                          frame.normals_gt.at(1, y, x),
                          frame.normals_gt.at(2, y, x)};
      if (std::isnan(n[0])) continue;
      ++with_gt;
      ASSERT_NEAR(n[0] * n[0] + n[1] * n[1] + n[2] * n[2], 1.0, 1e-5);
      const double r[3] = {K_inv[0] * x + K_inv[2], K_inv[4] * y + K_inv[5],
                           1.0};
      ASSERT_LE(n[0] * r[0] + n[1] * r[1] + n[2] * r[2], 1e-6);
    }
  }
  EXPECT_GT(with_gt, 10000);
  // Normals of the recorded (noise-free) depth agree with the model's: the
  // median angle is far below the depth case's errors.
  const NormalMap from_depth =
      synthetic::normalsFromDepth(frame.depth, frame.K);
  const AngularErrorStats agreement =
      angularError(from_depth, frame.normals_gt);
  EXPECT_LT(agreement.median_deg, 1.0);
  EXPECT_GT(agreement.within_11_25, 0.9);
  // The guide is the colour image at the depth pixels: the object is
  // brighter than the grey background around it.
  double object = 0.0, background = 0.0;
  int n_object = 0, n_background = 0;
  for (std::size_t i = 0; i < frame.depth.pixelCount(); ++i) {
    if (std::isnan(frame.depth.data()[i])) {
      background += frame.image.data()[i];
      ++n_background;
    } else {
      object += frame.image.data()[i];
      ++n_object;
    }
  }
  ASSERT_GT(n_background, 0);
  EXPECT_GT(object / n_object, background / n_background + 0.1);
}

}  // namespace
}  // namespace normal_fusion
