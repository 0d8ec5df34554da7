// KeyframeFrontend: the keyframe database (a map's keyframes saved, loaded
// in place of those held, or added to them) and the chains a loaded map
// resumes.
#include <algorithm>
#include <set>

#include "rotation_averaging/frontend/controllers/keyframe_frontend.h"
#include "frontend/controllers/keyframe_frontend_keyframe.h"

namespace rotation_averaging {

bool KeyframeFrontend::SnapshotDatabase(KeyframeDatabase* database, std::string* error) const {
  if (!options_.vocabulary) {
    if (error) *error = "the keyframe database needs a vocabulary (retrieval by voting keeps every feature)";
    return false;
  }
  database->feature_type = options_.features.type;
  database->num_words = options_.vocabulary->NumWords();
  database->vocabulary_fingerprint = options_.vocabulary->Fingerprint();
  database->keyframes.clear();
  database->keyframes.reserve(keyframes_.size());
  // Chains are numbered in the file as they come: a loaded chain and this
  // session's chain of the same camera stay apart.
  std::map<std::pair<int, std::string>, std::uint32_t> chain_ids;
  for (const std::unique_ptr<Keyframe>& kf : keyframes_) {
    StoredKeyframe& stored = database->keyframes.emplace_back();
    const std::string chain_camera = kf->loaded_chain >= 0 ? std::string() : kf->key.frame_id;
    stored.chain = chain_ids.emplace(std::make_pair(kf->loaded_chain, chain_camera), chain_ids.size()).first->second;
    stored.key = kf->key;
    stored.has_sequential = kf->has_sequential;
    stored.k = kf->k;
    if (kf->has_sequential) {
      stored.sequential_rotation = kf->sequential_rotation;
      stored.sequential_covariance = kf->sequential_covariance;
    }
    // A compact keyframe's descriptors are never changed in place (Compact
    // replaces them; a focal correction moves keypoints, which are copied):
    // sharing them with the snapshot is safe.
    stored.features =
        kf->compact ? kf->features : CompactFeatures(kf->features, options_.compact_features, kf->inlier_hits);
    stored.bow = kf->bow;
  }
  return true;
}

bool KeyframeFrontend::SaveDatabase(const std::string& path, std::string* error) const {
  KeyframeDatabase database;
  return SnapshotDatabase(&database, error) && WriteKeyframeDatabase(path, database, error);
}

bool KeyframeFrontend::LoadDatabase(const std::string& path, std::string* error) {
  return TakeDatabase(path, /*add=*/false, nullptr, error);
}

bool KeyframeFrontend::AddDatabase(const std::string& path, std::size_t* already_held, std::string* error,
                                   std::vector<KeyframeRelativeRotation>* links) {
  const int first_added = static_cast<int>(keyframes_.size());
  std::size_t shared = 0;
  if (!TakeDatabase(path, /*add=*/true, &shared, error)) return false;
  if (already_held) *already_held = shared;
  if (links) *links = shared == 0 ? LinkAddedKeyframes(first_added) : std::vector<KeyframeRelativeRotation>();
  return true;
}

bool KeyframeFrontend::TakeDatabase(const std::string& path, bool add, std::size_t* already_held,
                                    std::string* error) {
  if (!options_.vocabulary) {
    if (error) *error = path + ": a keyframe database needs a vocabulary to load into (vocabulary: none)";
    return false;
  }
  KeyframeDatabase database;
  if (!ReadKeyframeDatabase(path, options_.vocabulary->Fingerprint(), &database, error)) return false;
  if (database.feature_type != options_.features.type || database.num_words != options_.vocabulary->NumWords()) {
    if (error) *error = path + ": keyframes of another feature type or vocabulary size";
    return false;
  }
  // Everything read and checked: now replace what is held, or add to it.
  if (!add) {
    keyframes_.clear();
    by_camera_.clear();
    held_pairs_.clear();  // their keyframes are gone
    loaded_chains_.clear();
    keys_.clear();
    due_compaction_.clear();
    inverted_index_ = std::make_unique<InvertedIndex>(options_.vocabulary->NumWords());
    const std::uint64_t duplicates = stats_.duplicate_keyframes;
    stats_ = KeyframeFrontendStats();
    stats_.duplicate_keyframes = duplicates;
  }
  // A keyframe already held (added maps share the history they were saved
  // from) is the same keyframe: skipped. The rest of its chain then starts
  // a chain of its own, since a sequential rotation relates only neighbours.
  std::size_t skipped = 0;
  std::map<std::uint32_t, int> chain_index;  // the file's chain -> loaded_chains_ index
  for (StoredKeyframe& stored : database.keyframes) {
    if (keys_.count(stored.key)) {
      ++skipped;
      chain_index.erase(stored.chain);
      continue;
    }
    auto kf = std::make_unique<Keyframe>();
    kf->key = stored.key;
    kf->k = stored.k;
    kf->sequential_rotation = stored.sequential_rotation;
    kf->sequential_covariance = stored.sequential_covariance;
    kf->features = std::move(stored.features);
    kf->bow = std::move(stored.bow);
    kf->compact = true;
    auto chain = chain_index.find(stored.chain);
    kf->has_sequential = stored.has_sequential && chain != chain_index.end();
    if (chain == chain_index.end()) {
      chain = chain_index.emplace(stored.chain, static_cast<int>(loaded_chains_.size())).first;
      loaded_chains_.emplace_back();
    }
    const int index = static_cast<int>(keyframes_.size());
    kf->loaded_chain = chain->second;
    kf->camera_position = static_cast<int>(loaded_chains_[chain->second].size());
    loaded_chains_[chain->second].push_back(index);
    inverted_index_->Add(index, kf->bow);
    keys_.insert(kf->key);
    stats_.keyframe_bytes += KeyframeBytes(*kf);
    stats_.compact_bytes += KeyframeBytes(*kf);
    ++stats_.loaded_keyframes;
    keyframes_.push_back(std::move(kf));
  }
  if (!add) ResumeChains();
  if (already_held) *already_held = skipped;
  return true;
}

void KeyframeFrontend::ResumeChains() {
  // Each camera's newest loaded chain becomes its chain again. Started
  // afresh, a camera's next keyframes would find the keyframes just before
  // the restart only by retrieval: as loop closures, which take the
  // candidates older places would have had and leave out the window pairs
  // (results/restart.md).
  std::map<std::string, int> newest;  // camera -> loaded chain
  for (int c = 0; c < static_cast<int>(loaded_chains_.size()); ++c) {
    if (loaded_chains_[c].empty()) continue;
    const Keyframe& last = *keyframes_[loaded_chains_[c].back()];
    auto it = newest.find(last.key.frame_id);
    if (it == newest.end() || keyframes_[loaded_chains_[it->second].back()]->key.stamp_ns < last.key.stamp_ns) {
      newest[last.key.frame_id] = c;
    }
  }
  for (const auto& [camera, c] : newest) {
    std::vector<int>& chain = by_camera_[camera];
    chain = std::move(loaded_chains_[c]);
    loaded_chains_[c].clear();
    for (int index : chain) {
      keyframes_[index]->loaded_chain = -1;
      keyframes_[index]->resumed = true;
    }
    ++stats_.resumed_chains;
  }
}

}  // namespace rotation_averaging
