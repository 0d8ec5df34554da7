// The keyframe database file: the keyframes of an image front end as it
// saves them beside a map (KeyframeFrontend::SaveDatabase), so that a node
// restarted on the map, or a later session, relates new images to them.
//
// Binary, in the machine's byte order: a 44-byte header (the magic
// "ROTAVG-KEYFRAMES", the format version, the vocabulary's fingerprint, the
// size of the contents and their checksum), then the contents: feature type,
// vocabulary size, keyframe count and every keyframe (key, chain, intrinsics,
// sequential rotation and covariance, compact features, bag of words).
// Version 2 checksums the contents with XXH3-64 (several GB/s: loading a large
// map is not held up by it); version 1 files (FNV-1a) are still read.
#ifndef ROTATION_AVERAGING_FRONTEND_IO_KEYFRAME_DATABASE_H_
#define ROTATION_AVERAGING_FRONTEND_IO_KEYFRAME_DATABASE_H_

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "rotation_averaging/core/controllers/online_averager.h"
#include "rotation_averaging/frontend/features/features.h"
#include "rotation_averaging/frontend/features/vocabulary.h"

namespace rotation_averaging {

// One keyframe as the database holds it.
struct StoredKeyframe {
  KeyframeKey key;
  // Keyframes of one chain (one camera's sequence in one session) share it,
  // in order; chain ids are numbered from 0 in the order they first appear.
  std::uint32_t chain = 0;
  bool has_sequential = false;  // sequential edge from the previous keyframe of its chain
  Eigen::Matrix3d k = Eigen::Matrix3d::Identity();  // intrinsics of the image its features come from
  Eigen::Matrix3d sequential_rotation = Eigen::Matrix3d::Identity();  // R_prev,this
  Eigen::Matrix3d sequential_covariance = Eigen::Matrix3d::Zero();
  ImageFeatures features;  // compact (CompactFeatures), with their vocabulary words
  BowVector bow;
};

struct KeyframeDatabase {
  FeatureType feature_type = FeatureType::kSift;
  int num_words = 0;                        // of the vocabulary the words belong to
  std::uint64_t vocabulary_fingerprint = 0;  // Vocabulary::Fingerprint()
  std::vector<StoredKeyframe> keyframes;
};

// Writes atomically (WriteFileAtomically), streaming: no copy of the whole
// contents is held in memory.
bool WriteKeyframeDatabase(const std::string& path, const KeyframeDatabase& database, std::string* error);

// Reads a database and checks all of it before returning: the magic, the
// version, the vocabulary (its fingerprint must be `vocabulary_fingerprint`),
// the size and the checksum, then every keyframe (bounds, finite values,
// intrinsics, words within the vocabulary, no repeated key, chains in
// order). A file that fails any check is refused with the reason, and
// `database` is left as it was.
bool ReadKeyframeDatabase(const std::string& path, std::uint64_t vocabulary_fingerprint, KeyframeDatabase* database,
                          std::string* error);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_IO_KEYFRAME_DATABASE_H_
