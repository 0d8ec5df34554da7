// Public header of rotation_averaging::core (docs/embedding.md).
// Robust losses rho(s) of the squared residual norm s = |r|^2, with the Ceres
// convention: an edge contributes rho(s) / 2 to the cost, rho(0) = 0 and
// rho'(0) = 1 so that every loss behaves like least squares near zero.
// Evaluate fills rho[0] = rho(s), rho[1] = rho'(s), rho[2] = rho''(s).
// `a` is the scale: the residual magnitude (same unit as r) at which the loss
// starts to down-weight. For MAGSAC it is sigma_max.
#ifndef ROTATION_AVERAGING_CORE_ESTIMATORS_ROBUST_LOSS_H_
#define ROTATION_AVERAGING_CORE_ESTIMATORS_ROBUST_LOSS_H_

#include <memory>
#include <string>
#include <vector>

namespace rotation_averaging {

class RobustLoss {
 public:
  virtual ~RobustLoss() = default;
  virtual void Evaluate(double s, double rho[3]) const = 0;
  // IRLS weight rho'(s).
  double Weight(double s) const {
    double rho[3];
    Evaluate(s, rho);
    return rho[1];
  }
};

// rho(s) = s.
class SquaredLoss : public RobustLoss {
 public:
  void Evaluate(double s, double rho[3]) const override;
};

// rho(s) = s                   for s <= a^2
//        = 2 a sqrt(s) - a^2   for s >  a^2.
class HuberLoss : public RobustLoss {
 public:
  explicit HuberLoss(double a) : a_(a), b_(a * a) {}
  void Evaluate(double s, double rho[3]) const override;

 private:
  double a_, b_;
};

// rho(s) = 2 a^2 (sqrt(1 + s / a^2) - 1)   (pseudo-Huber; L1 for large s).
class SoftL1Loss : public RobustLoss {
 public:
  explicit SoftL1Loss(double a) : b_(a * a), c_(1.0 / (a * a)) {}
  void Evaluate(double s, double rho[3]) const override;

 private:
  double b_, c_;
};

// rho(s) = 4 a^2 ((1 + s / a^2)^(1/4) - 1): a smooth L0.5, rho ~ |r|^(1/2)
// for large residuals. (The paper's code uses 2 a^1.5 s^(1/4), which is not
// differentiable at 0 and whose coded derivative does not match its value;
// this form has the same tail and a consistent quadratic core.)
class LHalfLoss : public RobustLoss {
 public:
  explicit LHalfLoss(double a) : b_(a * a), c_(1.0 / (a * a)) {}
  void Evaluate(double s, double rho[3]) const override;

 private:
  double b_, c_;
};

// rho(s) = a^2 log(1 + s / a^2).
class CauchyLoss : public RobustLoss {
 public:
  explicit CauchyLoss(double a) : b_(a * a), c_(1.0 / (a * a)) {}
  void Evaluate(double s, double rho[3]) const override;

 private:
  double b_, c_;
};

// rho(s) = a^2 s / (s + a^2)   (Geman-McClure; bounded by a^2).
class GemanMcClureLoss : public RobustLoss {
 public:
  explicit GemanMcClureLoss(double a) : b_(a * a) {}
  void Evaluate(double s, double rho[3]) const override;

 private:
  double b_;
};

// rho(s) = a^2 / 3 (1 - (1 - s / a^2)^3)   for s <= a^2
//        = a^2 / 3                         for s >  a^2   (Tukey biweight).
class TukeyLoss : public RobustLoss {
 public:
  explicit TukeyLoss(double a) : b_(a * a) {}
  void Evaluate(double s, double rho[3]) const override;

 private:
  double b_;
};

// MAGSAC++ loss (Barath et al. 2020) as used for rotation averaging by Zhang,
// Larsson and Barath (CVPR 2023): rho(r) = w(0) - w(r), where the weight
//
//   w(r) = 1/sigma_max * Int_0^sigma_max p(r | sigma) d sigma,
//   p(r | sigma) = 2 C(nu) sigma^-nu r^(nu-1) exp(-r^2 / (2 sigma^2)) for r < k sigma
//
// marginalises a chi (nu degrees of freedom) inlier density over a uniform
// noise scale. In general
//   w(r) = C(nu) 2^((nu-1)/2) / sigma_max *
//          [Gamma((nu-1)/2, r^2 / (2 sigma_max^2)) - Gamma((nu-1)/2, k^2 / 2)]
// with Gamma the upper incomplete gamma function. For rotations nu = 3,
// Gamma(1, x) = exp(-x), and with the normalisation rho'(0) = 1:
//
//   rho(s) = 2 sigma_max^2 (1 - exp(-s / (2 sigma_max^2)))   for s <= k^2 sigma_max^2
//          = 2 sigma_max^2 (1 - exp(-k^2 / 2))              beyond (constant),
//   rho'(s) = exp(-s / (2 sigma_max^2)) inside, 0 beyond,
//
// with k = 3.3682 = sqrt(chi2_0.99(3)). No inlier threshold is set by hand:
// sigma_max only bounds the noise scale.
class MagsacLoss : public RobustLoss {
 public:
  static constexpr double kChiQuantile = 3.3682;  // sqrt of the 0.99 quantile of chi2(3)
  explicit MagsacLoss(double sigma_max);
  void Evaluate(double s, double rho[3]) const override;

 private:
  double two_sigma2_, cutoff_s_, outer_value_;
};

enum class LossType { kSquared, kHuber, kSoftL1, kLHalf, kCauchy, kGemanMcClure, kTukey, kMagsac };

const std::vector<LossType>& AllLossTypes();
const char* LossTypeName(LossType type);  // "squared", "huber", "soft_l1", "l0.5", ...
bool ParseLossType(const std::string& text, LossType* type);
std::string LossTypeChoices();  // "squared, huber, ...": every name of AllLossTypes, for messages
std::unique_ptr<RobustLoss> CreateLoss(LossType type, double scale);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CORE_ESTIMATORS_ROBUST_LOSS_H_
