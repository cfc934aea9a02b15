#include "preprocess/generator.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <numbers>
#include <string>
#include <vector>

#include "common/errors.hpp"
#include "common/geometry.hpp"
#include "preprocess/mesh_sampler.hpp"

namespace pointillist::preprocess {
namespace {

constexpr double kPi = std::numbers::pi;
// Disk area = kCoverage / density: the same rule as normals.hpp and the mesh sampler.
constexpr double kCoverage = 3.0;
// Local object coordinates and copy translations are multiples of this.
constexpr double kGrid = 1.0 / 4096.0;

using Rgba = std::array<std::uint8_t, 4>;

double quantize(double v) {
  return std::round(v / kGrid) * kGrid;
}
double smoothstep(double e0, double e1, double x) {
  const double t = std::clamp((x - e0) / (e1 - e0), 0.0, 1.0);
  return t * t * (3.0 - 2.0 * t);
}

std::uint8_t channel(double v) {
  return static_cast<std::uint8_t>(std::clamp(std::lround(v), 0L, 255L));
}
Rgba rgb(double r, double g, double b) {
  return {channel(r), channel(g), channel(b), 255};
}
Rgba mix(const Rgba& a, const Rgba& b, double t) {
  return rgb(a[0] + (b[0] - a[0]) * t, a[1] + (b[1] - a[1]) * t, a[2] + (b[2] - a[2]) * t);
}
// A little per-point variation so that surfaces do not look flat-shaded.
Rgba jitter(const Rgba& c, Rng& rng, double amount) {
  const double d = rng.uniform(-amount, amount);
  return rgb(c[0] + d, c[1] + d, c[2] + d);
}

struct Sample {
  Vec3d p;
  Vec3d n;
  // Stretch of the surface against the (u, v) grid along one direction (height
  // fields: 1 / n_z along the slope); the radius grows with it so that the
  // elongated cells stay covered.
  double stretch = 1.0;
};
using ColorFn = std::function<Rgba(const Vec3d& p, const Vec3d& n, Rng& rng)>;

ColorFn solid(Rgba c, double noise = 6.0) {
  return [c, noise](const Vec3d&, const Vec3d&, Rng& rng) { return jitter(c, rng, noise); };
}

// A surface given by an area-preserving map from the unit square, so that a
// jittered grid in (u, v) gives evenly spread points (random points leave
// holes: with disks of 3x the area per point a Poisson sampling still misses 5%).
struct Shape {
  double area = 0.0;    // for the point budget
  double aspect = 1.0;  // width / height of the (u, v) domain in surface units
  std::function<Sample(double u, double v)> at;
  ColorFn color;
  double weight = 1.0;  // relative density
};

// Parallelogram origin + u*eu + v*ev; the normal points away from `inside`.
Shape rectangle(const Vec3d& origin, const Vec3d& eu, const Vec3d& ev, const Vec3d& inside,
                ColorFn color) {
  Vec3d n = cross(eu, ev);
  const double area = length(n);
  n = scale(n, 1.0 / area);
  const Vec3d centre = add(add(origin, scale(eu, 0.5)), scale(ev, 0.5));
  if (dot(n, sub(centre, inside)) < 0) n = scale(n, -1.0);
  return {area, length(eu) / length(ev),
          [=](double u, double v) {
            return Sample{add(add(origin, scale(eu, u)), scale(ev, v)), n};
          },
          std::move(color)};
}

Shape triangle(const Vec3d& a, const Vec3d& b, const Vec3d& c, const Vec3d& inside, ColorFn color) {
  Vec3d n = cross(sub(b, a), sub(c, a));
  const double area = 0.5 * length(n);
  n = normalized(n);
  if (dot(n, sub(scale(add(add(a, b), c), 1.0 / 3.0), inside)) < 0) n = scale(n, -1.0);
  return {area, 1.0,
          [=](double u, double v) {
            const double r = std::sqrt(u);
            return Sample{add(add(scale(a, 1 - r), scale(b, r * (1 - v))), scale(c, r * v)), n};
          },
          std::move(color)};
}

// Axis-aligned box faces (no bottom when `onGround`), normals outward.
void box(std::vector<Shape>& shapes, const Vec3d& centre, const Vec3d& half, bool onGround,
         bool withTop, const ColorFn& color) {
  const double a = half[0], b = half[1], h = half[2];
  const Vec3d lo = sub(centre, half);
  shapes.push_back(rectangle(add(lo, {2 * a, 0, 0}), {0, 2 * b, 0}, {0, 0, 2 * h}, centre, color));
  shapes.push_back(rectangle(lo, {0, 2 * b, 0}, {0, 0, 2 * h}, centre, color));
  shapes.push_back(rectangle(add(lo, {0, 2 * b, 0}), {2 * a, 0, 0}, {0, 0, 2 * h}, centre, color));
  shapes.push_back(rectangle(lo, {2 * a, 0, 0}, {0, 0, 2 * h}, centre, color));
  if (withTop) {
    shapes.push_back(
        rectangle(add(lo, {0, 0, 2 * h}), {2 * a, 0, 0}, {0, 2 * b, 0}, centre, color));
  }
  if (!onGround) shapes.push_back(rectangle(lo, {2 * a, 0, 0}, {0, 2 * b, 0}, centre, color));
}

// Side of a vertical cylinder.
Shape cylinder(const Vec3d& base, double r, double h, ColorFn color) {
  return {2 * kPi * r * h, 2 * kPi * r / h,
          [=](double u, double v) {
            const double phi = 2 * kPi * u;
            const Vec3d n{std::cos(phi), std::sin(phi), 0};
            return Sample{add(base, {r * n[0], r * n[1], v * h}), n};
          },
          std::move(color)};
}

// Sphere cap above z = zCut * r (zCut = -1: whole sphere, 0: upper hemisphere);
// z uniform is area-preserving (Archimedes' hat-box theorem).
Shape sphere(const Vec3d& centre, double r, double zCut, ColorFn color) {
  return {2 * kPi * r * r * (1 - zCut), 2 * kPi / (1 - zCut),
          [=](double u, double v) {
            const double z = zCut + (1 - zCut) * v, phi = 2 * kPi * u;
            const double s = std::sqrt(std::max(0.0, 1 - z * z));
            const Vec3d n{s * std::cos(phi), s * std::sin(phi), z};
            return Sample{add(centre, scale(n, r)), n};
          },
          std::move(color)};
}

// Side of an upright cone (base radius at `base`, apex h above).
Shape cone(const Vec3d& base, double radius, double h, ColorFn color) {
  const double slant = std::sqrt(radius * radius + h * h);
  return {kPi * radius * slant, kPi * radius / slant,
          [=](double u, double v) {
            const double f = std::sqrt(v);  // distance from the apex, area-weighted
            const double phi = 2 * kPi * u;
            const double c = std::cos(phi), s = std::sin(phi);
            const Vec3d p = add(base, {f * radius * c, f * radius * s, (1 - f) * h});
            return Sample{p, Vec3d{c * h / slant, s * h / slant, radius / slant}};
          },
          std::move(color)};
}

// Torus (or an arc of it, phi in [phi0, phi1]) around axis e3 through `centre`,
// ring in the plane of e1, e2. theta inverts the area CDF (theta + k sin theta) / 2pi.
Shape torus(const Vec3d& centre, const Vec3d& e1, const Vec3d& e2, const Vec3d& e3, double big,
            double small, double phi0, double phi1, ColorFn color) {
  const double k = small / big;
  return {(phi1 - phi0) * 2 * kPi * small * big, (phi1 - phi0) * big / (2 * kPi * small),
          [=](double u, double v) {
            const double target = 2 * kPi * v;
            double theta = target;
            for (int i = 0; i < 30; ++i) {  // Newton; the derivative is at least 1 - k > 0
              const double step =
                  (theta + k * std::sin(theta) - target) / (1 + k * std::cos(theta));
              theta = std::clamp(theta - step, 0.0, 2 * kPi);
              if (std::abs(step) < 1e-13) break;
            }
            const double phi = phi0 + (phi1 - phi0) * u;
            const Vec3d radial = add(scale(e1, std::cos(phi)), scale(e2, std::sin(phi)));
            const Vec3d n = add(scale(radial, std::cos(theta)), scale(e3, std::sin(theta)));
            return Sample{add(add(centre, scale(radial, big)), scale(n, small)), n};
          },
          std::move(color)};
}

// Calls emit(u, v) exactly `count` times, one point per cell of a jittered
// nu x nv grid shaped after `aspect`; the few surplus cells are dropped evenly.
template <class Emit>
void jitteredGrid(std::size_t count, double aspect, Rng& rng, Emit&& emit) {
  if (count == 0) return;
  const double wanted = std::sqrt(static_cast<double>(count) * std::max(aspect, 1e-9));
  const std::size_t nu =
      std::clamp<std::size_t>(static_cast<std::size_t>(std::llround(wanted)), 1, count);
  const std::size_t nv = (count + nu - 1) / nu;
  const std::size_t total = nu * nv, excess = total - count;
  for (std::size_t k = 0; k < total; ++k) {
    if ((k + 1) * excess / total != k * excess / total) continue;
    const double u = (static_cast<double>(k % nu) + rng.uniform()) / static_cast<double>(nu);
    const double v = (static_cast<double>(k / nu) + rng.uniform()) / static_cast<double>(nv);
    emit(u, v);
  }
}

// `count` points spread over the shapes in proportion to area x weight
// (largest remainder). Radii: disks of kCoverage times the area per point.
std::vector<Splat> sampleShapes(const std::vector<Shape>& shapes, std::size_t count, Rng& rng,
                                bool quantized) {
  std::vector<Splat> out;
  if (count == 0 || shapes.empty()) return out;
  double total = 0;
  for (const Shape& s : shapes) total += s.area * s.weight;
  std::vector<std::size_t> counts(shapes.size());
  std::vector<std::pair<double, std::size_t>> remainders;
  std::size_t assigned = 0;
  for (std::size_t i = 0; i < shapes.size(); ++i) {
    const double exact = static_cast<double>(count) * shapes[i].area * shapes[i].weight / total;
    counts[i] = static_cast<std::size_t>(exact);
    assigned += counts[i];
    remainders.emplace_back(exact - static_cast<double>(counts[i]), i);
  }
  std::sort(remainders.begin(), remainders.end(), [](const auto& a, const auto& b) {
    return a.first > b.first || (a.first == b.first && a.second < b.second);
  });
  for (std::size_t k = 0; assigned < count; ++k, ++assigned) ++counts[remainders[k].second];

  out.reserve(count);
  for (std::size_t i = 0; i < shapes.size(); ++i) {
    if (counts[i] == 0) continue;
    const Shape& shape = shapes[i];
    const double perPoint = shape.area / static_cast<double>(counts[i]);
    jitteredGrid(counts[i], shape.aspect, rng, [&](double u, double v) {
      const Sample sample = shape.at(u, v);
      const Rgba c = shape.color(sample.p, sample.n, rng);
      Splat s{};
      for (std::size_t d = 0; d < 3; ++d) {
        s.position[d] = static_cast<float>(quantized ? quantize(sample.p[d]) : sample.p[d]);
        s.normal[d] = static_cast<float>(sample.n[d]);
      }
      s.radius = static_cast<float>(std::sqrt(kCoverage * perPoint / kPi) * sample.stretch);
      std::copy(c.begin(), c.end(), s.color);
      out.push_back(s);
    });
  }
  return out;
}

// Appends one exact translated copy per offset (offsets are quantized too).
void placeCopies(const std::vector<Splat>& local, const std::vector<Vec3d>& offsets,
                 std::vector<Splat>& out) {
  for (const Vec3d& offset : offsets) {
    const float t[3] = {static_cast<float>(quantize(offset[0])),
                        static_cast<float>(quantize(offset[1])),
                        static_cast<float>(quantize(offset[2]))};
    for (Splat s : local) {
      for (std::size_t d = 0; d < 3; ++d) s.position[d] += t[d];
      out.push_back(s);
    }
  }
}

// ---------------------------------------------------------------- the city

// Windows and a door on house walls, chosen from local coordinates.
ColorFn wallColor(Rgba wall, double windowSpacing, double doorHalfWidth) {
  return [=](const Vec3d& p, const Vec3d& n, Rng& rng) {
    const double along = std::abs(n[0]) > 0.5 ? p[1] : p[0];
    const double cell = along / windowSpacing - std::floor(along / windowSpacing);
    const bool door = n[1] < -0.5 && std::abs(p[0]) < doorHalfWidth && p[2] < 2.2;
    if (door) return jitter(rgb(95, 60, 40), rng, 4);
    const double floorZ = std::fmod(p[2], 3.0);
    const bool window = cell > 0.3 && cell < 0.7 && floorZ > 1.0 && floorZ < 2.2 && p[2] > 0.8;
    if (window) return jitter(rgb(60, 85, 120), rng, 5);
    return jitter(wall, rng, 7);
  };
}

std::vector<Shape> gableHouse() {
  std::vector<Shape> shapes;
  const Vec3d inside{0, 0, 2};
  const double a = 6, b = 4, h = 5, ridge = 8, overhang = 0.5;
  const ColorFn walls = wallColor(rgb(226, 214, 188), 3.0, 0.8);
  box(shapes, {0, 0, h / 2}, {a, b, h / 2}, true, false, walls);
  shapes.push_back(triangle({a, -b, h}, {a, b, h}, {a, 0, ridge}, inside, walls));
  shapes.push_back(triangle({-a, -b, h}, {-a, b, h}, {-a, 0, ridge}, inside, walls));
  const ColorFn tiles = [](const Vec3d& p, const Vec3d&, Rng& rng) {
    const double row = std::fmod(p[2] * 4.0, 1.0);
    return jitter(row < 0.15 ? rgb(130, 50, 38) : rgb(176, 74, 52), rng, 8);
  };
  const double eaveDrop = overhang * (ridge - h) / b;
  for (const double side : {1.0, -1.0}) {
    shapes.push_back(
        rectangle({-a - overhang, side * (b + overhang), h - eaveDrop}, {2 * (a + overhang), 0, 0},
                  {0, -side * (b + overhang), ridge - h + eaveDrop}, {0, 0, 0}, tiles));
  }
  box(shapes, {3, 2, ridge - 0.5}, {0.45, 0.45, 1.3}, true, true, solid(rgb(120, 60, 50)));
  return shapes;
}

std::vector<Shape> towerHouse() {
  std::vector<Shape> shapes;
  const double a = 5, h = 11;
  box(shapes, {0, 0, h / 2}, {a, a, h / 2}, true, false, wallColor(rgb(170, 182, 196), 2.5, 1.0));
  shapes.push_back(rectangle({-a, -a, h}, {2 * a, 0, 0}, {0, 2 * a, 0}, {0, 0, 0},
                             solid(rgb(105, 105, 110), 10)));  // gravel roof
  // Parapet and a small observatory dome on the flat roof.
  box(shapes, {0, 0, h + 0.4}, {a, a, 0.4}, true, false, solid(rgb(120, 125, 135)));
  shapes.push_back(sphere({0, 0, h}, 2.4, 0.0, [](const Vec3d& p, const Vec3d&, Rng& rng) {
    return jitter(mix(rgb(200, 205, 215), rgb(240, 242, 246), (p[2] - 11) / 2.4), rng, 4);
  }));
  return shapes;
}

ColorFn bark() {
  return solid(rgb(98, 70, 45), 8);
}
ColorFn foliage(Rgba base) {
  return [base](const Vec3d& p, const Vec3d&, Rng& rng) {
    // Lighter towards the top, as if lit from above.
    const double light = std::clamp((p[2] - 3.0) * 10.0, -25.0, 35.0);
    return jitter(rgb(base[0] + light * 0.5, base[1] + light, base[2] + light * 0.4), rng, 14);
  };
}

std::vector<Shape> broadleafTree() {
  std::vector<Shape> shapes;
  shapes.push_back(cylinder({0, 0, -0.5}, 0.35, 3.0, bark()));  // ends just inside the crown
  shapes.push_back(sphere({0, 0, 4.6}, 2.3, -1.0, foliage(rgb(62, 128, 48))));
  shapes.push_back(sphere({0.7, 0.4, 5.9}, 1.6, -1.0, foliage(rgb(72, 140, 52))));
  return shapes;
}

std::vector<Shape> conifer() {
  std::vector<Shape> shapes;
  shapes.push_back(cylinder({0, 0, -0.5}, 0.3, 2.1, bark()));
  shapes.push_back(cone({0, 0, 1.4}, 2.3, 4.2, foliage(rgb(34, 92, 50))));
  shapes.push_back(cone({0, 0, 3.8}, 1.6, 3.6, foliage(rgb(40, 104, 56))));
  return shapes;
}

std::vector<Shape> column() {
  std::vector<Shape> shapes;
  const ColorFn marble = [](const Vec3d& p, const Vec3d&, Rng& rng) {
    // Fluting: darker grooves every 1/20 turn.
    const double phi = std::atan2(p[1], p[0]) / (2 * kPi) * 20.0;
    const double groove = phi - std::floor(phi);
    return jitter(groove < 0.2 ? rgb(205, 200, 192) : rgb(238, 234, 226), rng, 4);
  };
  box(shapes, {0, 0, 0.25}, {1.0, 1.0, 0.25}, true, true, solid(rgb(215, 210, 200)));
  shapes.push_back(cylinder({0, 0, 0.5}, 0.8, 9.0, marble));
  box(shapes, {0, 0, 9.8}, {1.1, 1.1, 0.3}, false, true, solid(rgb(225, 220, 210)));
  return shapes;
}

struct Hill {
  double x, y, height, sigma;
};

class City {
 public:
  explicit City(std::uint64_t seed) : rng_(seed) {
    for (int i = 0; i < 7; ++i) {
      const double angle = rng_.uniform(0, 2 * kPi);
      const double r = rng_.uniform(150, 215);
      hills_.push_back(
          {r * std::cos(angle), r * std::sin(angle), rng_.uniform(18, 48), rng_.uniform(22, 45)});
    }
  }

  // Terrain height: flat town inside |x|,|y| < 100, hills outside.
  double height(double x, double y) const {
    const double d = std::max(std::abs(x), std::abs(y));
    const double mask = smoothstep(100, 145, d);
    if (mask == 0) return 0;
    double h = 5 + 3 * std::sin(0.05 * x) * std::sin(0.043 * y + 1.0);
    for (const Hill& hill : hills_) {
      const double dx = x - hill.x, dy = y - hill.y;
      h += hill.height * std::exp(-(dx * dx + dy * dy) / (2 * hill.sigma * hill.sigma));
    }
    return mask * h;
  }

  Vec3d terrainNormal(double x, double y) const {
    const double e = 0.05;
    const double dx = (height(x + e, y) - height(x - e, y)) / (2 * e);
    const double dy = (height(x, y + e) - height(x, y - e)) / (2 * e);
    return normalized({-dx, -dy, 1});
  }

  PointCloud build(std::size_t target) {
    // Budgets: shares of the target, the terrain takes the rest (exact total).
    const auto share = [&](double f) {
      return static_cast<std::size_t>(f * static_cast<double>(target));
    };
    for (int ix = 0; ix < 6; ++ix) {
      for (int iy = 0; iy < 6; ++iy) {
        const double x = -75 + 30 * ix, y = -75 + 30 * iy;
        if (std::abs(x) < 20 && std::abs(y) < 20) continue;  // the plaza
        ((ix + iy) % 2 == 0 ? gableSpots_ : towerSpots_).push_back({x, y, 0});
      }
    }
    std::vector<Vec3d> broadleafSpots, coniferSpots;
    for (int k = -5; k <= 5; ++k) {  // street trees just inside the town edge
      if (k == 0) continue;          // where the main roads leave town
      const double t = 15.0 * k;
      for (const Vec3d& spot :
           {Vec3d{t, -96, 0}, Vec3d{t, 96, 0}, Vec3d{-96, t, 0}, Vec3d{96, t, 0}}) {
        broadleafSpots.push_back(spot);
      }
    }
    for (int k = 0; k < 70; ++k) {  // forest on the hills
      double x = 0, y = 0;
      do {
        x = std::round(rng_.uniform(-195, 195));
        y = std::round(rng_.uniform(-195, 195));
      } while (std::max(std::abs(x), std::abs(y)) < 115);
      (k % 3 == 0 ? broadleafSpots : coniferSpots).push_back({x, y, height(x, y)});
    }
    const std::vector<Vec3d> columnSpots = ring(16, 28.0);

    std::vector<Splat> splats;
    splats.reserve(target);
    const auto instanced = [&](const std::vector<Shape>& shapes, const std::vector<Vec3d>& spots,
                               double fraction) {
      const std::size_t each = share(fraction) / spots.size();
      const std::vector<Splat> local = sampleShapes(shapes, each, rng_, true);
      placeCopies(local, spots, splats);
    };
    instanced(gableHouse(), gableSpots_, 0.13);
    instanced(towerHouse(), towerSpots_, 0.12);
    instanced(broadleafTree(), broadleafSpots, 0.07);
    instanced(conifer(), coniferSpots, 0.05);
    instanced(column(), columnSpots, 0.05);
    append(splats, sampleShapes(domeBuilding(), share(0.10), rng_, false));
    append(splats, sampleShapes(ringAndGates(), share(0.04), rng_, false));
    sampleTerrain(target - std::min(target, splats.size()), splats);

    PointCloud cloud;
    cloud.splats = std::move(splats);
    cloud.hasNormals = cloud.hasColors = cloud.hasRadii = true;
    cloud.source = "generator:city";
    return cloud;
  }

 private:
  static void append(std::vector<Splat>& out, const std::vector<Splat>& more) {
    out.insert(out.end(), more.begin(), more.end());
  }

  static std::vector<Vec3d> ring(int n, double r) {
    std::vector<Vec3d> spots;
    for (int i = 0; i < n; ++i) {
      const double a = 2 * kPi * i / n;
      spots.push_back({r * std::cos(a), r * std::sin(a), 0});
    }
    return spots;
  }

  static std::vector<Shape> domeBuilding() {
    std::vector<Shape> shapes;
    const double r = kDrumRadius, drum = 8;
    shapes.push_back(cylinder({0, 0, 0}, r, drum, [](const Vec3d& p, const Vec3d&, Rng& rng) {
      const double a = std::atan2(p[1], p[0]) / (2 * kPi) * 24.0;
      const double cell = a - std::floor(a);
      const bool window = cell > 0.35 && cell < 0.65 && p[2] > 3 && p[2] < 6.2;
      if (window) return jitter(rgb(50, 60, 80), rng, 4);
      return jitter(p[2] > 7.4 ? rgb(170, 140, 100) : rgb(206, 178, 128), rng, 7);
    }));
    shapes.push_back(sphere({0, 0, drum}, r, 0.0, [](const Vec3d& p, const Vec3d&, Rng& rng) {
      const double a = std::atan2(p[1], p[0]) / (2 * kPi) * 16.0;
      const double rib = std::abs(a - std::round(a));
      if (rib < 0.04) return jitter(rgb(214, 172, 70), rng, 6);  // gilded ribs
      const double t = (p[2] - 8) / 18;
      return jitter(mix(rgb(62, 140, 118), rgb(110, 180, 160), t), rng, 7);  // copper patina
    }));
    shapes.push_back(cylinder({0, 0, drum + r - 0.3}, 2.0, 3.0, solid(rgb(230, 225, 210))));
    shapes.push_back(sphere({0, 0, drum + r + 4.1}, 1.4, -1.0, solid(rgb(232, 190, 80))));
    return shapes;
  }

  static std::vector<Shape> ringAndGates() {
    std::vector<Shape> shapes;
    shapes.push_back(torus({0, 0, 11.0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, 28.0, 0.9, 0, 2 * kPi,
                           solid(rgb(225, 218, 200))));
    const ColorFn stone = [](const Vec3d& p, const Vec3d&, Rng& rng) {
      const double course = std::fmod(std::abs(p[2]) * 2.0, 1.0);
      return jitter(course < 0.12 ? rgb(140, 120, 105) : rgb(186, 164, 140), rng, 6);
    };
    // Half-torus arches standing across the four main roads.
    for (const double s : {1.0, -1.0}) {
      shapes.push_back(
          torus({40 * s, 0, 0}, {0, 1, 0}, {0, 0, 1}, {1, 0, 0}, 5.5, 0.7, 0, kPi, stone));
      shapes.push_back(
          torus({0, 40 * s, 0}, {1, 0, 0}, {0, 0, 1}, {0, 1, 0}, 5.5, 0.7, 0, kPi, stone));
    }
    return shapes;
  }

  Rgba terrainColor(double x, double y, double h, const Vec3d& n) {
    const double d = std::max(std::abs(x), std::abs(y));
    if (d < 100) {
      const double rr = std::sqrt(x * x + y * y);
      if (rr < 38) {  // paved plaza with rings
        const double ringPhase = std::fmod(rr, 4.0);
        return jitter(ringPhase < 0.4 ? rgb(160, 150, 135) : rgb(198, 188, 168), rng_, 6);
      }
      const double fx = std::abs(x - 30 * std::round(x / 30));
      const double fy = std::abs(y - 30 * std::round(y / 30));
      const double f = std::min(fx, fy);
      if (f < 3) {  // asphalt with a dashed centre line
        const double along = fx < fy ? y : x;
        const bool line = f < 0.3 && std::fmod(std::abs(along), 6.0) < 3.0;
        return line ? rgb(235, 230, 200) : jitter(rgb(72, 72, 78), rng_, 5);
      }
      if (f < 4.2) return jitter(rgb(175, 172, 165), rng_, 5);  // pavement
      return jitter(rgb(96, 146, 72), rng_, 10);                // lawns
    }
    // Hills: meadow patches, earth higher up, rock on steep slopes, snow on the tops.
    const double patches =
        std::sin(0.045 * x + 1.7 * std::sin(0.031 * y)) * std::sin(0.052 * y + 0.8);
    Rgba c = patches > 0 ? mix(rgb(88, 140, 64), rgb(136, 156, 70), smoothstep(0.0, 0.5, patches))
                         : mix(rgb(88, 140, 64), rgb(58, 112, 52), smoothstep(0.0, -0.5, patches));
    c = mix(c, rgb(128, 112, 76), smoothstep(12, 30, h));
    const double steep = 1 - n[2];
    c = mix(c, rgb(128, 124, 120), smoothstep(0.15, 0.35, steep));
    c = mix(c, rgb(246, 246, 252), smoothstep(44, 50, h + 15 * (0.3 - steep)));
    return jitter(c, rng_, 9);
  }

  // The terrain as height-field patches over rectangles of the xy plane: the
  // town at full density, the hills in two rings at half and a quarter.
  void sampleTerrain(std::size_t count, std::vector<Splat>& out) {
    struct Band {
      double inner, outer, weight;
    };
    std::vector<Shape> patches;
    const auto patch = [&](double x0, double x1, double y0, double y1, double weight) {
      Shape shape;
      shape.area = (x1 - x0) * (y1 - y0);
      shape.aspect = (x1 - x0) / (y1 - y0);
      shape.weight = weight;
      shape.at = [this, x0, x1, y0, y1](double u, double v) {
        const double x = x0 + (x1 - x0) * u, y = y0 + (y1 - y0) * v;
        const Vec3d n = terrainNormal(x, y);
        return Sample{{x, y, height(x, y)}, n, 1.0 / n[2]};
      };
      shape.color = [this](const Vec3d& p, const Vec3d& n, Rng&) {
        return terrainColor(p[0], p[1], p[2], n);
      };
      patches.push_back(std::move(shape));
    };
    patch(-100, 100, -100, 100, 1.0);
    for (const Band& band : {Band{100, 150, 0.5}, Band{150, 200, 0.25}}) {
      const double a = band.inner, b = band.outer;
      patch(-b, b, a, b, band.weight);
      patch(-b, b, -b, -a, band.weight);
      patch(-b, -a, -a, a, band.weight);
      patch(a, b, -a, a, band.weight);
    }
    // Oversample by the hidden share, drop hidden points, then thin evenly to `count`.
    double hidden = std::numbers::pi * kDrumRadius * kDrumRadius;
    hidden += static_cast<double>(gableSpots_.size()) * 12 * 8 +
              static_cast<double>(towerSpots_.size()) * 10 * 10;
    double weighted = 0;
    for (const Shape& shape : patches) weighted += shape.area * shape.weight;
    double factor = 1.0 / (1.0 - hidden / weighted) + 0.005;
    std::vector<Splat> visible;
    for (;;) {
      const auto oversampled = static_cast<std::size_t>(static_cast<double>(count) * factor) + 16;
      visible.clear();
      for (const Splat& s : sampleShapes(patches, oversampled, rng_, false)) {
        if (!occupied(static_cast<double>(s.position[0]), static_cast<double>(s.position[1]))) {
          visible.push_back(s);
        }
      }
      if (visible.size() >= count) break;
      factor *= 1.05;
    }
    const std::size_t have = visible.size();
    for (std::size_t i = 0; i < have; ++i) {
      if ((i + 1) * count / have != i * count / have) out.push_back(visible[i]);
    }
  }

  // Ground hidden under buildings is not sampled (nor would a scanner see it).
  bool occupied(double x, double y) const {
    if (x * x + y * y < kDrumRadius * kDrumRadius) return true;
    for (const Vec3d& s : gableSpots_) {
      if (std::abs(x - s[0]) < 6 && std::abs(y - s[1]) < 4) return true;
    }
    for (const Vec3d& s : towerSpots_) {
      if (std::abs(x - s[0]) < 5 && std::abs(y - s[1]) < 5) return true;
    }
    return false;
  }

  static constexpr double kDrumRadius = 18;
  Rng rng_;
  std::vector<Hill> hills_;
  std::vector<Vec3d> gableSpots_, towerSpots_;
};

PointCloud simpleShape(const std::vector<Shape>& shapes, std::size_t count, std::uint64_t seed,
                       const std::string& name) {
  Rng rng(seed);
  PointCloud cloud;
  cloud.splats = sampleShapes(shapes, count, rng, false);
  cloud.hasNormals = cloud.hasColors = cloud.hasRadii = true;
  cloud.source = "generator:" + name;
  return cloud;
}

// Colour from the normal, so orientation problems show.
Rgba normalColor(const Vec3d&, const Vec3d& n, Rng&) {
  return rgb(127.5 * (n[0] + 1), 127.5 * (n[1] + 1), 127.5 * (n[2] + 1));
}

}  // namespace

std::vector<std::string> generatorNames() {
  return {"city", "sphere", "torus"};
}

PointCloud generateScene(const std::string& name, std::size_t targetPoints, std::uint64_t seed) {
  if (targetPoints == 0) throw UsageError("generator '" + name + "': point count must be positive");
  if (name == "city") return City(seed).build(targetPoints);
  if (name == "sphere") {
    return simpleShape({sphere({0, 0, 0}, 1.0, -1.0, normalColor)}, targetPoints, seed, name);
  }
  if (name == "torus") {
    return simpleShape(
        {torus({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, 0, 1}, 1.0, 0.35, 0, 2 * kPi, normalColor)},
        targetPoints, seed, name);
  }
  std::string known;
  for (const std::string& n : generatorNames()) known += (known.empty() ? "" : ", ") + n;
  throw UsageError("unknown generator '" + name + "' (known: " + known + ")");
}

}  // namespace pointillist::preprocess
