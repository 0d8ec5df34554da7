#include "rotation_averaging/core/scene/view_graph.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <numeric>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {

const char* EdgeSourceName(EdgeSource source) {
  switch (source) {
    case EdgeSource::kRig: return "rig";
    case EdgeSource::kSequential: return "sequential";
    case EdgeSource::kLoopClosure: return "loop_closure";
    case EdgeSource::kOther: return "other";
  }
  return "other";
}

bool ParseEdgeSource(const std::string& text, EdgeSource* source) {
  for (EdgeSource s : {EdgeSource::kRig, EdgeSource::kSequential, EdgeSource::kLoopClosure, EdgeSource::kOther}) {
    if (text == EdgeSourceName(s)) {
      *source = s;
      return true;
    }
  }
  return false;
}

RelativeRotation RelativeRotation::Inverted() const {
  RelativeRotation inv = *this;
  std::swap(inv.view1, inv.view2);
  inv.rotation = rotation.transpose();
  // M_12 = R_12 Exp(eta)  =>  M_21 = Exp(-eta) R_21 = R_21 Exp(-R_12 eta).
  inv.covariance = rotation * covariance * rotation.transpose();
  return inv;
}

std::size_t ViewGraph::EdgeKeyHash::operator()(const EdgeKey& k) const {
  std::size_t h = std::hash<ViewId>()(k.a);
  h ^= std::hash<ViewId>()(k.b) + 0x9e3779b97f4a7c15ULL + (h << 6) + (h >> 2);
  h ^= static_cast<std::size_t>(k.source) + 0x9e3779b97f4a7c15ULL + (h << 6) + (h >> 2);
  return h;
}

ViewGraph::EdgeKey ViewGraph::KeyOf(ViewId v1, ViewId v2, EdgeSource source) {
  return EdgeKey{std::min(v1, v2), std::max(v1, v2), source};
}

bool ViewGraph::AddView(ViewId id, const std::string& name) {
  if (view_index_.count(id)) return false;
  view_index_[id] = views_.size();
  views_.push_back(View{id, name.empty() ? std::to_string(id) : name});
  return true;
}

const View* ViewGraph::FindView(ViewId id) const {
  auto it = view_index_.find(id);
  return it == view_index_.end() ? nullptr : &views_[it->second];
}

bool ViewGraph::RemoveView(ViewId id) {
  auto it = view_index_.find(id);
  if (it == view_index_.end()) return false;
  for (std::size_t e = edges_.size(); e-- > 0;) {
    if (edges_[e].view1 == id || edges_[e].view2 == id) EraseEdgeAt(e);
  }
  const std::size_t index = it->second;
  view_index_.erase(it);
  if (index + 1 != views_.size()) {
    views_[index] = std::move(views_.back());
    view_index_[views_[index].id] = index;
  }
  views_.pop_back();
  return true;
}

bool ViewGraph::ValidateEdge(RelativeRotation* edge, std::string* error, bool* covariance_repaired) const {
  *covariance_repaired = false;
  auto fail = [error](const std::string& why) {
    if (error) *error = why;
    return false;
  };
  if (edge->view1 == edge->view2) return fail("edge relates view " + std::to_string(edge->view1) + " to itself");
  if (!edge->rotation.allFinite()) return fail("relative rotation is not finite");
  const double orthogonality =
      (edge->rotation.transpose() * edge->rotation - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (orthogonality > validation_.rotation_tolerance || edge->rotation.determinant() <= 0.0) {
    return fail("relative rotation is not a rotation (|R^T R - I| = " + std::to_string(orthogonality) +
                ", det = " + std::to_string(edge->rotation.determinant()) + ")");
  }
  edge->rotation = ProjectToSO3(edge->rotation);
  if (edge->num_inliers < 0) return fail("negative inlier count");
  if (!edge->has_covariance) return true;

  Eigen::Matrix3d& c = edge->covariance;
  if (!c.allFinite()) return fail("covariance is not finite");
  const double scale = c.cwiseAbs().maxCoeff();
  if (!(scale > 0.0)) return fail("covariance is zero");
  const double asymmetry = (c - c.transpose()).cwiseAbs().maxCoeff() / scale;
  if (asymmetry > validation_.covariance_asymmetry_tolerance) {
    return fail("covariance is not symmetric (relative asymmetry " + std::to_string(asymmetry) + ")");
  }
  if (asymmetry > 0.0) *covariance_repaired = true;
  c = 0.5 * (c + c.transpose());
  // The common case, a covariance well inside the cone, is decided by one
  // Cholesky factorisation instead of an eigendecomposition (most of the
  // validation's time when reading large graphs): if c - (trace floor) I is
  // positive definite, the smallest eigenvalue is above the floor, since the
  // trace bounds the largest.
  const double trace = c.trace();
  if (trace > 0.0) {
    const Eigen::LLT<Eigen::Matrix3d> above_floor(c - trace * validation_.covariance_eigenvalue_floor *
                                                          Eigen::Matrix3d::Identity());
    if (above_floor.info() == Eigen::Success) return true;
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(c);
  Eigen::Vector3d values = eig.eigenvalues();
  const double largest = values.maxCoeff();
  if (!(largest > 0.0)) return fail("covariance has no positive eigenvalue");
  const double floor = largest * validation_.covariance_eigenvalue_floor;
  if (values.minCoeff() < floor) {
    values = values.cwiseMax(floor);
    c = eig.eigenvectors() * values.asDiagonal() * eig.eigenvectors().transpose();
    *covariance_repaired = true;
  }
  return true;
}

AddEdgeResult ViewGraph::AddEdge(const RelativeRotation& input, std::string* error, DuplicatePolicy duplicates) {
  if (!HasView(input.view1) || !HasView(input.view2)) {
    if (input.view1 == input.view2) {
      ++stats_.rejected_self_loop;
      if (error) *error = "edge relates view " + std::to_string(input.view1) + " to itself";
      return AddEdgeResult::kRejected;
    }
    ++stats_.rejected_unknown_view;
    if (error) {
      *error = "edge refers to unknown view " + std::to_string(HasView(input.view1) ? input.view2 : input.view1);
    }
    return AddEdgeResult::kRejected;
  }
  RelativeRotation edge = input;
  bool repaired = false;
  std::string why;
  if (!ValidateEdge(&edge, &why, &repaired)) {
    if (edge.view1 == edge.view2) {
      ++stats_.rejected_self_loop;
    } else if (why.rfind("covariance", 0) == 0) {
      ++stats_.rejected_bad_covariance;
    } else {
      ++stats_.rejected_bad_rotation;
    }
    if (error) *error = why;
    return AddEdgeResult::kRejected;
  }
  if (repaired) ++stats_.repaired_covariance;
  std::vector<std::size_t>& same = edge_index_[KeyOf(edge.view1, edge.view2, edge.source)];
  if (duplicates == DuplicatePolicy::kReplace) {
    for (std::size_t k : same) {
      if (edges_[k].channel != edge.channel) continue;
      edges_[k] = edge;
      ++stats_.edges_replaced;
      return AddEdgeResult::kReplaced;
    }
  }
  same.push_back(edges_.size());
  edges_.push_back(edge);
  ++stats_.edges_added;
  return AddEdgeResult::kAdded;
}

void ViewGraph::EraseEdgeAt(std::size_t index) {
  auto unlink = [this](std::size_t at, std::size_t replacement) {
    const RelativeRotation& e = edges_[at];
    auto it = edge_index_.find(KeyOf(e.view1, e.view2, e.source));
    std::vector<std::size_t>& list = it->second;
    for (std::size_t& k : list) {
      if (k == at) k = replacement;
    }
    list.erase(std::remove(list.begin(), list.end(), static_cast<std::size_t>(-1)), list.end());
    if (list.empty()) edge_index_.erase(it);
  };
  const std::size_t last = edges_.size() - 1;
  unlink(index, static_cast<std::size_t>(-1));
  if (index != last) {
    unlink(last, index);
    edges_[index] = edges_[last];
  }
  edges_.pop_back();
}

bool ViewGraph::RemoveEdge(ViewId view1, ViewId view2, EdgeSource source) {
  auto it = edge_index_.find(KeyOf(view1, view2, source));
  if (it == edge_index_.end()) return false;
  const std::vector<std::size_t> indices = it->second;
  // Erase from the highest index down so that the others stay valid.
  std::vector<std::size_t> sorted = indices;
  std::sort(sorted.rbegin(), sorted.rend());
  for (std::size_t k : sorted) EraseEdgeAt(k);
  return true;
}

void ViewGraph::Clear() {
  views_.clear();
  view_index_.clear();
  edges_.clear();
  edge_index_.clear();
  stats_ = InputStats();
}

std::vector<std::vector<ViewId>> ViewGraph::ConnectedComponents() const {
  // Union-find over view indices.
  std::vector<std::size_t> parent(views_.size());
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&parent](std::size_t x) {
    while (parent[x] != x) {
      parent[x] = parent[parent[x]];
      x = parent[x];
    }
    return x;
  };
  for (const RelativeRotation& e : edges_) {
    const std::size_t a = find(view_index_.at(e.view1));
    const std::size_t b = find(view_index_.at(e.view2));
    if (a != b) parent[std::max(a, b)] = std::min(a, b);
  }
  std::unordered_map<std::size_t, std::size_t> root_to_component;
  std::vector<std::vector<ViewId>> components;
  for (std::size_t i = 0; i < views_.size(); ++i) {
    const std::size_t root = find(i);
    auto it = root_to_component.find(root);
    if (it == root_to_component.end()) {
      it = root_to_component.emplace(root, components.size()).first;
      components.emplace_back();
    }
    components[it->second].push_back(views_[i].id);
  }
  for (auto& c : components) std::sort(c.begin(), c.end());
  std::stable_sort(components.begin(), components.end(), [](const auto& a, const auto& b) {
    return a.size() != b.size() ? a.size() > b.size() : a.front() < b.front();
  });
  return components;
}

}  // namespace rotation_averaging
