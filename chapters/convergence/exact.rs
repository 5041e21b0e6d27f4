//! Exact ambient occlusion for the estimator the tutorial traces: cosine-weighted directions over
//! the hemisphere, rays of length `R`, occlusion = the fraction that hit something. Each answer is
//! the probability that such a ray hits, computed in f64, and checked against a Monte Carlo of
//! real rays against real planes (the tests below).

use std::f64::consts::PI;

// ANCHOR: exact
/// A point between two parallel planes a distance `h` apart: a ray at angle θ from the normal
/// meets the other plane after h / cos θ, so it hits when cos θ > h / R. Cosine-weighted,
/// P(cos θ > c) = 1 − c².
pub fn between_planes(h: f64, radius: f64) -> f64 {
    if h >= radius { 0.0 } else { 1.0 - (h / radius).powi(2) }
}

/// A floor point at distance `x` from an infinite wall (or a wall point at height `x` above an
/// infinite floor): S(x / R) / π, with S(a) = acos a − a √(1 − a²), the area of the part of the
/// unit disc beyond a chord at distance a (the cosine-weighted directions, projected onto the
/// floor, are uniform on the unit disc; those that reach the wall within R project beyond x / R).
pub fn beside_wall(x: f64, radius: f64) -> f64 {
    let a = (x / radius).clamp(0.0, 1.0);
    (a.acos() - a * (1.0 - a * a).sqrt()) / PI
}
// ANCHOR_END: exact

#[cfg(test)]
mod tests {
    use super::*;

    /// Common's seeded generator (SplitMix64): the same numbers on every machine.
    struct Random(common::scene::Random);
    impl Random {
        fn uniform(&mut self) -> f64 {
            (self.0.next_u64() >> 11) as f64 / (1u64 << 53) as f64
        }
        /// A cosine-weighted direction around +z: uniform on the disc, lifted.
        fn cosine_direction(&mut self) -> [f64; 3] {
            let (u, v) = (self.uniform(), self.uniform());
            let r = u.sqrt();
            let phi = 2.0 * PI * v;
            [r * phi.cos(), r * phi.sin(), (1.0 - u).sqrt()]
        }
    }

    /// The fraction of `n` cosine-weighted rays of length `radius` from the origin (normal +z)
    /// that `hits` says hit, and the standard error of that fraction.
    fn monte_carlo(n: u32, mut hits: impl FnMut([f64; 3]) -> bool) -> (f64, f64) {
        let mut random = Random(common::scene::Random(7));
        let count = (0..n).filter(|_| hits(random.cosine_direction())).count() as f64;
        let p = count / n as f64;
        (p, (p * (1.0 - p) / n as f64).sqrt().max(1e-4))
    }

    #[test]
    fn between_planes_matches_rays_against_a_plane() {
        let radius = 1.0;
        for h in [0.0, 0.1, 0.5, 0.9, 1.0, 2.0] {
            // The other plane is z = h: a ray d reaches it at t = h / d.z, a hit if t <= R.
            let (p, se) = monte_carlo(200_000, |d| d[2] > 0.0 && h / d[2] <= radius);
            let exact = between_planes(h, radius);
            assert!((p - exact).abs() < 4.0 * se, "h {h}: Monte Carlo {p}, exact {exact}");
        }
    }

    #[test]
    fn beside_wall_matches_rays_against_a_wall() {
        let radius = 1.0;
        for x in [0.0, 0.05, 0.3, 0.7, 0.99, 1.5] {
            // The wall is the plane X = -x (the floor point at the origin, normal +z): a ray d
            // with d.x < 0 reaches it at t = x / -d.x, a hit if t <= R. The wall is infinite.
            let (p, se) = monte_carlo(200_000, |d| d[0] < 0.0 && x / -d[0] <= radius);
            let exact = beside_wall(x, radius);
            assert!((p - exact).abs() < 4.0 * se, "x {x}: Monte Carlo {p}, exact {exact}");
        }
        assert!((beside_wall(0.0, 1.0) - 0.5).abs() < 1e-12, "against the wall: half the sky");
    }
}
