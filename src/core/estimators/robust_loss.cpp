#include "rotation_averaging/core/estimators/robust_loss.h"

#include <cmath>
#include <stdexcept>

namespace rotation_averaging {

void SquaredLoss::Evaluate(double s, double rho[3]) const {
  rho[0] = s;
  rho[1] = 1.0;
  rho[2] = 0.0;
}

void HuberLoss::Evaluate(double s, double rho[3]) const {
  if (s > b_) {
    const double r = std::sqrt(s);
    rho[0] = 2.0 * a_ * r - b_;
    rho[1] = a_ / r;
    rho[2] = -rho[1] / (2.0 * s);
  } else {
    rho[0] = s;
    rho[1] = 1.0;
    rho[2] = 0.0;
  }
}

void SoftL1Loss::Evaluate(double s, double rho[3]) const {
  const double sum = 1.0 + s * c_;
  const double root = std::sqrt(sum);
  rho[0] = 2.0 * b_ * (root - 1.0);
  rho[1] = 1.0 / root;
  rho[2] = -0.5 * c_ * rho[1] / sum;
}

void LHalfLoss::Evaluate(double s, double rho[3]) const {
  const double sum = 1.0 + s * c_;
  const double quarter = std::pow(sum, 0.25);
  rho[0] = 4.0 * b_ * (quarter - 1.0);
  rho[1] = quarter / sum;  // sum^(-3/4)
  rho[2] = -0.75 * c_ * rho[1] / sum;
}

void CauchyLoss::Evaluate(double s, double rho[3]) const {
  const double sum = 1.0 + s * c_;
  const double inv = 1.0 / sum;
  rho[0] = b_ * std::log1p(s * c_);
  rho[1] = inv;
  rho[2] = -c_ * inv * inv;
}

void GemanMcClureLoss::Evaluate(double s, double rho[3]) const {
  const double sum = s + b_;
  const double ratio = b_ / sum;
  rho[0] = b_ * s / sum;
  rho[1] = ratio * ratio;
  rho[2] = -2.0 * rho[1] / sum;
}

void TukeyLoss::Evaluate(double s, double rho[3]) const {
  if (s <= b_) {
    const double v = 1.0 - s / b_;
    rho[0] = b_ / 3.0 * (1.0 - v * v * v);
    rho[1] = v * v;
    rho[2] = -2.0 * v / b_;
  } else {
    rho[0] = b_ / 3.0;
    rho[1] = 0.0;
    rho[2] = 0.0;
  }
}

MagsacLoss::MagsacLoss(double sigma_max)
    : two_sigma2_(2.0 * sigma_max * sigma_max),
      cutoff_s_(kChiQuantile * kChiQuantile * sigma_max * sigma_max),
      outer_value_(two_sigma2_ * -std::expm1(-0.5 * kChiQuantile * kChiQuantile)) {}

void MagsacLoss::Evaluate(double s, double rho[3]) const {
  if (s <= cutoff_s_) {
    // One transcendental call: expm1 keeps rho accurate for small s, and
    // e = 1 + expm1 is exact enough for the weight (absolute error 1e-16).
    const double em1 = std::expm1(-s / two_sigma2_);
    const double e = 1.0 + em1;
    rho[0] = -two_sigma2_ * em1;
    rho[1] = e;
    rho[2] = -e / two_sigma2_;
  } else {
    rho[0] = outer_value_;
    rho[1] = 0.0;
    rho[2] = 0.0;
  }
}

const std::vector<LossType>& AllLossTypes() {
  static const std::vector<LossType> kAll = {LossType::kSquared, LossType::kHuber,        LossType::kSoftL1,
                                             LossType::kLHalf,   LossType::kCauchy,       LossType::kGemanMcClure,
                                             LossType::kTukey,   LossType::kMagsac};
  return kAll;
}

const char* LossTypeName(LossType type) {
  switch (type) {
    case LossType::kSquared: return "squared";
    case LossType::kHuber: return "huber";
    case LossType::kSoftL1: return "soft_l1";
    case LossType::kLHalf: return "l0.5";
    case LossType::kCauchy: return "cauchy";
    case LossType::kGemanMcClure: return "geman_mcclure";
    case LossType::kTukey: return "tukey";
    case LossType::kMagsac: return "magsac";
  }
  return "?";
}

std::string LossTypeChoices() {
  std::string names;
  for (LossType t : AllLossTypes()) names += (names.empty() ? "" : ", ") + std::string(LossTypeName(t));
  return names;
}

bool ParseLossType(const std::string& text, LossType* type) {
  for (LossType t : AllLossTypes()) {
    if (text == LossTypeName(t)) {
      *type = t;
      return true;
    }
  }
  if (text == "l2" || text == "trivial") {
    *type = LossType::kSquared;
    return true;
  }
  return false;
}

std::unique_ptr<RobustLoss> CreateLoss(LossType type, double scale) {
  if (type != LossType::kSquared && !(scale > 0.0 && std::isfinite(scale))) {
    throw std::invalid_argument("loss scale must be positive and finite");
  }
  switch (type) {
    case LossType::kSquared: return std::make_unique<SquaredLoss>();
    case LossType::kHuber: return std::make_unique<HuberLoss>(scale);
    case LossType::kSoftL1: return std::make_unique<SoftL1Loss>(scale);
    case LossType::kLHalf: return std::make_unique<LHalfLoss>(scale);
    case LossType::kCauchy: return std::make_unique<CauchyLoss>(scale);
    case LossType::kGemanMcClure: return std::make_unique<GemanMcClureLoss>(scale);
    case LossType::kTukey: return std::make_unique<TukeyLoss>(scale);
    case LossType::kMagsac: return std::make_unique<MagsacLoss>(scale);
  }
  return std::make_unique<SquaredLoss>();
}

}  // namespace rotation_averaging
