#include "rotation_averaging/sim/rig_scene.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

constexpr double kTexelM = 0.01;  // texture resolution: 1 cm

// Rotation taking rig coordinates to the optical frame of a camera looking
// along rig direction `forward` with rig z up.
Eigen::Matrix3d CameraFromRig(const Eigen::Vector3d& forward) {
  const Eigen::Vector3d z = forward.normalized();
  const Eigen::Vector3d y = -Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d x = y.cross(z);
  Eigen::Matrix3d r;
  r.row(0) = x.transpose();
  r.row(1) = y.transpose();
  r.row(2) = z.transpose();
  return r;
}

// Random shapes in random greys on a grey ground, lightly blurred: plenty of
// corners and blobs, no repetition. One draw per statement: C++ leaves the
// order of a call's arguments unspecified, and drawing inside one call made
// the texture depend on the compiler (the draws follow the order gcc gave
// those calls, last argument first; util/random_draws.h).
cv::Mat MakeTexture(double width_m, double height_m, std::uint64_t seed) {
  const int w = std::max(8, static_cast<int>(std::lround(width_m / kTexelM)));
  const int h = std::max(8, static_cast<int>(std::lround(height_m / kTexelM)));
  cv::RNG rng(seed);
  cv::Mat t(h, w, CV_8UC1, cv::Scalar(rng.uniform(70, 180)));
  const int shapes = static_cast<int>(70.0 * width_m * height_m) + 20;
  for (int k = 0; k < shapes; ++k) {
    const int cy = rng.uniform(0, h);
    const int cx = rng.uniform(0, w);
    const cv::Point c(cx, cy);
    const cv::Scalar grey(rng.uniform(0, 256));
    switch (rng.uniform(0, 4)) {
      case 0:
        cv::circle(t, c, rng.uniform(3, 14), grey, cv::FILLED, cv::LINE_AA);
        break;
      case 1: {
        const float angle = rng.uniform(0.f, 180.f);
        const float height = rng.uniform(4.f, 30.f);
        const float width = rng.uniform(4.f, 30.f);
        const cv::RotatedRect rect(c, cv::Size2f(width, height), angle);
        cv::Point2f p[4];
        rect.points(p);
        std::vector<cv::Point> poly(p, p + 4);
        cv::fillConvexPoly(t, poly, grey, cv::LINE_AA);
        break;
      }
      case 2: {
        const int thickness = rng.uniform(1, 4);
        const int dy = rng.uniform(-40, 40);
        const int dx = rng.uniform(-40, 40);
        cv::line(t, c, c + cv::Point(dx, dy), grey, thickness, cv::LINE_AA);
        break;
      }
      default: {
        const double angle = rng.uniform(0.0, 180.0);
        const int half_height = rng.uniform(2, 10);
        const int half_width = rng.uniform(3, 20);
        cv::ellipse(t, c, cv::Size(half_width, half_height), angle, 0, 360, grey, cv::FILLED, cv::LINE_AA);
        break;
      }
    }
  }
  cv::GaussianBlur(t, t, cv::Size(0, 0), 0.8);
  cv::Mat f;
  t.convertTo(f, CV_32F);
  return f;
}

}  // namespace

// A textured rectangle: points o + u a + v b, 0 <= u <= U, 0 <= v <= V.
struct RigScene::Surface {
  Eigen::Vector3d origin, a, b, normal;
  double u_max = 0.0, v_max = 0.0;
  cv::Mat texture;  // CV_32F, kTexelM per texel

  double Sample(double u, double v) const {
    const double x = std::clamp(u / kTexelM, 0.0, texture.cols - 1.001);
    const double y = std::clamp(v / kTexelM, 0.0, texture.rows - 1.001);
    const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
    const double fx = x - x0, fy = y - y0;
    const float* r0 = texture.ptr<float>(y0);
    const float* r1 = texture.ptr<float>(y0 + 1);
    return (1 - fy) * ((1 - fx) * r0[x0] + fx * r0[x0 + 1]) + fy * ((1 - fx) * r1[x0] + fx * r1[x0 + 1]);
  }
};

RigScene::RigScene(const RigSceneOptions& options) : options_(options) {
  const char* names[] = {"cam_front", "cam_left", "cam_back", "cam_right"};
  const Eigen::Vector3d directions[] = {Eigen::Vector3d::UnitX(), Eigen::Vector3d::UnitY(), -Eigen::Vector3d::UnitX(),
                                        -Eigen::Vector3d::UnitY()};
  const int n = std::clamp(options_.num_cameras, 1, 4);
  for (int c = 0; c < n; ++c) {
    cameras_.push_back(RigCamera{names[c], CameraFromRig(directions[c]), 0.1 * directions[c]});
  }

  std::uint64_t seed = options_.seed * 1000;
  auto add = [&](const Eigen::Vector3d& origin, const Eigen::Vector3d& a, const Eigen::Vector3d& b, double u_max,
                 double v_max) {
    Surface s;
    s.origin = origin;
    s.a = a;
    s.b = b;
    s.normal = a.cross(b);
    s.u_max = u_max;
    s.v_max = v_max;
    s.texture = MakeTexture(u_max, v_max, ++seed);
    surfaces_.push_back(std::move(s));
  };
  // An axis-aligned box [lo, hi] as five (or six) faces.
  auto add_box = [&](const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, bool with_bottom) {
    const Eigen::Vector3d d = hi - lo;
    const Eigen::Vector3d ex = Eigen::Vector3d::UnitX(), ey = Eigen::Vector3d::UnitY(), ez = Eigen::Vector3d::UnitZ();
    add(lo, ex, ez, d.x(), d.z());                          // y = lo
    add(Eigen::Vector3d(lo.x(), hi.y(), lo.z()), ex, ez, d.x(), d.z());  // y = hi
    add(lo, ey, ez, d.y(), d.z());                          // x = lo
    add(Eigen::Vector3d(hi.x(), lo.y(), lo.z()), ey, ez, d.y(), d.z());  // x = hi
    add(Eigen::Vector3d(lo.x(), lo.y(), hi.z()), ex, ey, d.x(), d.y());  // top
    if (with_bottom) add(lo, ex, ey, d.x(), d.y());
  };
  const double e = options_.half_extent_m, h = options_.room_height_m;
  add_box(Eigen::Vector3d(-e, -e, 0.0), Eigen::Vector3d(e, e, h), /*with_bottom=*/true);  // the room
  add_box(Eigen::Vector3d(-0.4, -0.4, 0.0), Eigen::Vector3d(0.4, 0.4, h), false);        // pillar
  add_box(Eigen::Vector3d(e - 1.2, -0.5, 0.0), Eigen::Vector3d(e - 0.6, 0.6, 0.9), false);  // crates
  add_box(Eigen::Vector3d(-1.0, e - 1.1, 0.0), Eigen::Vector3d(0.3, e - 0.5, 1.2), false);
}

RigScene::~RigScene() = default;

Eigen::Matrix3d RigScene::Intrinsics() const {
  Eigen::Matrix3d k;
  k << options_.focal_px, 0.0, 0.5 * options_.width, 0.0, options_.focal_px, 0.5 * options_.height, 0.0, 0.0, 1.0;
  return k;
}

double RigScene::Phase(int capture) const {
  return DegToRad(options_.start_angle_deg) +
         2.0 * kPi * std::max(1, options_.laps) * capture / std::max(1, options_.num_captures);
}

Eigen::Vector3d RigScene::RigPosition(int capture) const {
  const double phase = Phase(capture);
  const int lap = static_cast<int>(std::floor((phase - DegToRad(options_.start_angle_deg)) / (2.0 * kPi) + 1e-9));
  // The capture after the last closes the last lap where it started.
  const double radius = options_.path_radius_m + options_.lap_radius_step_m * std::clamp(lap, 0, std::max(1, options_.laps) - 1);
  return Eigen::Vector3d(radius * std::cos(phase), radius * std::sin(phase),
                         options_.camera_height_m + 0.05 * std::sin(3.0 * phase));
}

Eigen::Matrix3d RigScene::WorldToRig(int capture) const {
  // Heading along the counter-clockwise circle (tangent), plus wobble.
  const double phase = Phase(capture);
  const double yaw = phase + 0.5 * kPi;
  const double wobble = DegToRad(options_.wobble_deg);
  const double pitch = wobble * std::sin(2.0 * phase), roll = wobble * std::cos(3.0 * phase);
  const Eigen::Matrix3d rig_to_world = (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
                                        Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
                                        Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
                                           .toRotationMatrix();
  return rig_to_world.transpose();
}

Eigen::Matrix3d RigScene::WorldToCamera(int capture, int camera) const {
  return cameras_.at(camera).camera_from_rig * WorldToRig(capture);
}

Eigen::Vector3d RigScene::CameraCentre(int capture, int camera) const {
  return RigPosition(capture) + WorldToRig(capture).transpose() * cameras_[camera].position_in_rig;
}

cv::Mat RigScene::Render(int capture, int camera, int margin_px) const {
  const std::uint64_t noise = options_.noise_seed != 0 ? options_.noise_seed : options_.seed;
  return RenderView(WorldToCamera(capture, camera), CameraCentre(capture, camera),
                    noise * 7919 + static_cast<std::uint64_t>(capture) * 104729 + camera * 15485863, margin_px);
}

cv::Mat RigScene::RenderView(const Eigen::Matrix3d& world_to_camera, const Eigen::Vector3d& centre,
                             std::uint64_t noise_seed, int margin_px) const {
  const Eigen::Matrix3d camera_to_world = world_to_camera.transpose();
  const int margin = std::max(0, margin_px);
  const double cx = 0.5 * options_.width + margin, cy = 0.5 * options_.height + margin, f = options_.focal_px;
  cv::Mat image(options_.height + 2 * margin, options_.width + 2 * margin, CV_8UC1);
  cv::RNG rng(noise_seed);
  const bool lit = options_.light_gain != 1.0 || options_.light_gradient != 0.0;
  for (int y = 0; y < image.rows; ++y) {
    std::uint8_t* row = image.ptr<std::uint8_t>(y);
    for (int x = 0; x < image.cols; ++x) {
      // Pixel x's centre is at x (OpenCV's convention, the one Intrinsics() is in).
      const Eigen::Vector3d d = camera_to_world * Eigen::Vector3d((x - cx) / f, (y - cy) / f, 1.0);
      double best = std::numeric_limits<double>::infinity(), value = 128.0;
      for (const Surface& s : surfaces_) {
        const double dn = d.dot(s.normal);
        if (std::abs(dn) < 1e-12) continue;
        const double t = (s.origin - centre).dot(s.normal) / dn;
        if (!(t > 1e-6) || t >= best) continue;
        const Eigen::Vector3d rel = centre + t * d - s.origin;
        const double u = rel.dot(s.a), v = rel.dot(s.b);
        if (u < 0.0 || v < 0.0 || u > s.u_max || v > s.v_max) continue;
        best = t;
        // Faces seen obliquely are a little darker: planes stay distinguishable.
        value = s.Sample(u, v) * (0.75 + 0.25 * std::abs(dn) / d.norm());
        if (lit) {
          const double across = std::clamp((centre + t * d).x() / options_.half_extent_m, -1.0, 1.0);
          value *= options_.light_gain * (1.0 + 0.5 * options_.light_gradient * across);
        }
      }
      const double noisy = value + (options_.noise_grey > 0.0 ? rng.gaussian(options_.noise_grey) : 0.0);
      row[x] = static_cast<std::uint8_t>(std::clamp(std::lround(noisy), 0L, 255L));
    }
  }
  return image;
}

}  // namespace rotation_averaging
