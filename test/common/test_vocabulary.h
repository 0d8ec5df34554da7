// A small SIFT vocabulary for tests: trained on views of a rendered room
// with other textures than the rooms the tests render, so that the images a
// test feeds its front end are never the training images.
#ifndef ROTATION_AVERAGING_TEST_COMMON_TEST_VOCABULARY_H_
#define ROTATION_AVERAGING_TEST_COMMON_TEST_VOCABULARY_H_

#include <gtest/gtest.h>

#include <memory>
#include <string>
#include <vector>

#include "rotation_averaging/sim/rig_scene.h"
#include "rotation_averaging/frontend/features/features.h"
#include "rotation_averaging/frontend/features/vocabulary.h"

namespace rotation_averaging {

// Trained once per test program (256 words, 12 views of the room of seed 11).
inline std::shared_ptr<const Vocabulary> TestVocabulary() {
  static const std::shared_ptr<const Vocabulary> vocabulary = [] {
    RigSceneOptions o;
    o.seed = 11;
    o.num_cameras = 1;
    o.num_captures = 12;
    o.WithWidth(480);
    const RigScene scene(o);
    FeatureOptions f;
    f.max_features = 800;
    std::vector<cv::Mat> descriptors;
    for (int c = 0; c < o.num_captures; ++c) descriptors.push_back(ExtractFeatures(scene.Render(c, 0), f).descriptors);
    VocabularyOptions options;
    options.words = 256;
    std::string error;
    std::shared_ptr<const Vocabulary> v = Vocabulary::Train(descriptors, options, &error);
    EXPECT_TRUE(v) << error;
    return v;
  }();
  return vocabulary;
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_TEST_COMMON_TEST_VOCABULARY_H_
