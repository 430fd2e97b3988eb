//! Chi-squared goodness-of-fit of every sampler against its own pdf (after Mitsuba 3's
//! `chi2.py`): bin the sphere, integrate the pdf over each cell numerically, compare with the
//! histogram of 10^6 samples, pool cells expecting fewer than 5 samples, require p > 0.01.

use std::f64::consts::PI;

use glam::{DVec3, Vec2, Vec3};
use render::envmap::{EnvMap, direction_to_uv, uv_to_direction};
use render::sampling::{
    EnvSampler, Frame, Rng, cosine_hemisphere_pdf, ggx, sample_cosine_hemisphere, sample_standard_normal_2d,
    sample_uniform_sphere, uniform_sphere_pdf,
};

const SAMPLES: usize = 1_000_000;
const SIGNIFICANCE: f64 = 0.01;

/// A parameterisation of the sphere by the unit square, in which the histogram cells are equal squares.
trait Domain {
    /// Unit-square coordinates of a unit direction.
    fn direction_to_square(&self, d: Vec3) -> (f64, f64);
    /// The direction at (x, y) and the Jacobian d(omega) / dx dy there.
    fn square_to_direction(&self, x: f64, y: f64) -> (Vec3, f64);
}

/// Spherical coordinates around `pole`: theta = pi x^power, phi = 2 pi y. A power above 1 spends
/// more cells near the pole (for sharp lobes centred on it).
struct PolarDomain {
    frame: Frame,
    power: f64,
}

impl Domain for PolarDomain {
    fn direction_to_square(&self, d: Vec3) -> (f64, f64) {
        let l = self.frame.to_local(d).as_dvec3().normalize();
        let theta = l.z.clamp(-1.0, 1.0).acos();
        let phi = l.y.atan2(l.x).rem_euclid(2.0 * PI);
        ((theta / PI).powf(1.0 / self.power), phi / (2.0 * PI))
    }

    fn square_to_direction(&self, x: f64, y: f64) -> (Vec3, f64) {
        let theta = PI * x.powf(self.power);
        let phi = 2.0 * PI * y;
        let local = DVec3::new(theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos());
        let jacobian = theta.sin() * PI * self.power * x.powf(self.power - 1.0) * 2.0 * PI;
        (self.frame.to_world(local.as_vec3()), jacobian)
    }
}

/// The env map's own lat-long (u, v): d(omega) = 2 pi^2 sin(pi v) du dv.
struct LatLongDomain;

impl Domain for LatLongDomain {
    fn direction_to_square(&self, d: Vec3) -> (f64, f64) {
        let uv = direction_to_uv(d);
        (uv.x as f64, uv.y as f64)
    }

    fn square_to_direction(&self, x: f64, y: f64) -> (Vec3, f64) {
        let d = uv_to_direction(Vec2::new(x as f32, y as f32));
        (d, 2.0 * PI * PI * (PI * y).sin())
    }
}

/// ln Gamma(x) for x > 0 (Lanczos, g = 7, 9 terms; ~1e-15 relative).
fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    let x = x - 1.0;
    let t = x + 7.5;
    let series: f64 = C[0] + (1..9).map(|i| C[i] / (x + i as f64)).sum::<f64>();
    0.5 * (2.0 * PI).ln() + (x + 0.5) * t.ln() - t + series.ln()
}

/// Upper regularised incomplete gamma Q(a, x): the chi-squared p-value is Q(dof / 2, chi2 / 2).
fn gamma_q(a: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 1.0;
    }
    let prefactor = (-x + a * x.ln() - ln_gamma(a)).exp();
    if x < a + 1.0 {
        // Series for P(a, x).
        let (mut term, mut sum, mut n) = (1.0 / a, 1.0 / a, a);
        while term.abs() > sum.abs() * 1e-15 {
            n += 1.0;
            term *= x / n;
            sum += term;
        }
        1.0 - sum * prefactor
    } else {
        // Lentz's continued fraction for Q(a, x).
        let tiny = 1e-300;
        let mut b = x + 1.0 - a;
        let mut c = 1.0 / tiny;
        let mut d = 1.0 / b;
        let mut h = d;
        for i in 1..10_000 {
            let an = -(i as f64) * (i as f64 - a);
            b += 2.0;
            d = an * d + b;
            d = if d.abs() < tiny { tiny } else { d };
            c = b + an / c;
            c = if c.abs() < tiny { tiny } else { c };
            d = 1.0 / d;
            let delta = d * c;
            h *= delta;
            if (delta - 1.0).abs() < 1e-15 {
                break;
            }
        }
        prefactor * h
    }
}

/// Runs the test: `sample` draws a direction (or None for a failed sample), `pdf` is its density.
/// Returns the p-value; also asserts the pdf integrates to 1 and no sample falls where pdf = 0.
fn chi2_test(
    name: &str,
    domain: &impl Domain,
    resolution: (usize, usize),
    mut sample: impl FnMut(&mut Rng) -> Option<Vec3>,
    pdf: impl Fn(Vec3) -> f64,
) -> f64 {
    let (nx, ny) = resolution;
    let mut observed = vec![0.0f64; nx * ny];
    let mut rng = Rng::new(7, 0);
    for _ in 0..SAMPLES {
        if let Some(d) = sample(&mut rng) {
            let (x, y) = domain.direction_to_square(d);
            let i = ((x * nx as f64) as usize).min(nx - 1);
            let j = ((y * ny as f64) as usize).min(ny - 1);
            observed[i * ny + j] += 1.0;
        }
    }
    // Integrate the pdf over each cell with a 16 x 16 midpoint rule in square coordinates.
    let sub = 16;
    let mut expected = vec![0.0f64; nx * ny];
    for i in 0..nx {
        for j in 0..ny {
            let mut sum = 0.0;
            for a in 0..sub {
                for b in 0..sub {
                    let x = (i as f64 + (a as f64 + 0.5) / sub as f64) / nx as f64;
                    let y = (j as f64 + (b as f64 + 0.5) / sub as f64) / ny as f64;
                    let (d, jacobian) = domain.square_to_direction(x, y);
                    sum += pdf(d) * jacobian;
                }
            }
            expected[i * ny + j] = sum / (sub * sub * nx * ny) as f64;
        }
    }
    let integral: f64 = expected.iter().sum();
    assert!(
        (integral - 1.0).abs() < 2e-3,
        "{name}: pdf integrates to {integral}, not 1"
    );
    // Cells straddling the edge of the support can get a few samples while all their
    // integration points miss it; more than that means samples where the pdf says none can be.
    let stray: f64 = observed
        .iter()
        .zip(&expected)
        .filter(|(_, e)| **e == 0.0)
        .map(|(o, _)| o)
        .sum();
    assert!(
        stray <= 1e-5 * SAMPLES as f64,
        "{name}: {stray} samples in cells where the pdf is 0"
    );
    // Pool the cells expecting fewer than 5 samples (smallest first) until the pool expects 5.
    let mut cells: Vec<(f64, f64)> = expected.iter().map(|e| e * SAMPLES as f64).zip(observed).collect();
    cells.sort_by(|a, b| a.0.total_cmp(&b.0));
    let (mut chi2, mut dof) = (0.0, 0usize);
    let (mut pool_e, mut pool_o) = (0.0, 0.0);
    for (e, o) in cells {
        if e < 5.0 {
            pool_e += e;
            pool_o += o;
            if pool_e >= 5.0 {
                chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
                dof += 1;
                (pool_e, pool_o) = (0.0, 0.0);
            }
        } else {
            chi2 += (o - e) * (o - e) / e;
            dof += 1;
        }
    }
    if pool_e > 0.0 {
        chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        dof += 1;
    }
    let p_value = gamma_q((dof - 1) as f64 / 2.0, chi2 / 2.0);
    println!(
        "{name}: chi2 = {chi2:.1}, dof = {}, p = {p_value:.4}, integral = {integral:.6}",
        dof - 1
    );
    p_value
}

fn assert_fits(p_value: f64, name: &str) {
    assert!(
        p_value > SIGNIFICANCE,
        "{name}: samples do not follow the pdf (p = {p_value:.2e})"
    );
}

#[test]
fn p_values_of_known_chi2_quantiles() {
    // chi2 = 3.841 at 1 dof and 18.307 at 10 dof are the 5% critical values.
    assert!((gamma_q(0.5, 3.841 / 2.0) - 0.05).abs() < 1e-3);
    assert!((gamma_q(5.0, 18.307 / 2.0) - 0.05).abs() < 1e-3);
    assert!((gamma_q(500.0, 1000.0 / 2.0) - 0.4941).abs() < 5e-3);
}

#[test]
fn uniform_sphere_fits_its_pdf() {
    let domain = PolarDomain {
        frame: Frame::from_normal(Vec3::Z),
        power: 1.0,
    };
    let p = chi2_test(
        "uniform sphere",
        &domain,
        (32, 64),
        |rng| Some(sample_uniform_sphere(rng.next_2d())),
        |_| uniform_sphere_pdf() as f64,
    );
    assert_fits(p, "uniform sphere");
}

/// A pair of standard normal values is a point of the plane whose normal CDFs `(Phi(x), Phi(y))`
/// are uniform on the unit square: carried onto the sphere by the uniform sphere's own
/// (area-preserving) map, the pairs must fit the uniform sphere's pdf.
#[test]
fn standard_normal_pairs_fit_their_pdf() {
    let domain = PolarDomain {
        frame: Frame::from_normal(Vec3::Z),
        power: 1.0,
    };
    let phi = |x: f32| 0.5 * (1.0 + erf(x as f64 / std::f64::consts::SQRT_2));
    let p = chi2_test(
        "standard normal pairs",
        &domain,
        (32, 64),
        |rng| {
            let n = sample_standard_normal_2d(rng.next_2d());
            Some(sample_uniform_sphere(Vec2::new(phi(n.x) as f32, phi(n.y) as f32)))
        },
        |_| uniform_sphere_pdf() as f64,
    );
    assert_fits(p, "standard normal pairs");
}

/// The error function (Abramowitz and Stegun 7.1.26, within 1.5e-7).
fn erf(x: f64) -> f64 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let poly =
        t * (0.254_829_592 + t * (-0.284_496_736 + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
    (1.0 - poly * (-x * x).exp()).copysign(x)
}

#[test]
fn cosine_hemisphere_fits_its_pdf() {
    let domain = PolarDomain {
        frame: Frame::from_normal(Vec3::Z),
        power: 1.0,
    };
    let p = chi2_test(
        "cosine hemisphere",
        &domain,
        (32, 64),
        |rng| Some(sample_cosine_hemisphere(rng.next_2d())),
        |d| cosine_hemisphere_pdf(d) as f64,
    );
    assert_fits(p, "cosine hemisphere");
}

#[test]
fn ggx_visible_normal_reflection_fits_its_pdf() {
    for roughness in [0.1f32, 0.3, 0.6, 0.9] {
        for theta_o_deg in [10.0f32, 50.0, 80.0] {
            let name = format!("GGX r = {roughness}, theta_o = {theta_o_deg} deg");
            let alpha = ggx::alpha_from_roughness(roughness);
            let theta_o = theta_o_deg.to_radians();
            let wo = Vec3::new(theta_o.sin(), 0.0, theta_o.cos());
            // Bin around the mirror direction, finer near it for sharp lobes.
            let mirror = Vec3::new(-wo.x, -wo.y, wo.z);
            let power = if roughness < 0.5 { 3.0 } else { 1.0 };
            let domain = PolarDomain {
                frame: Frame::from_normal(mirror),
                power,
            };
            let p = chi2_test(
                &name,
                &domain,
                (32, 64),
                |rng| {
                    let s = ggx::sample_reflection(wo, alpha, rng.next_2d());
                    let pdf = ggx::reflection_pdf(wo, s.wi, alpha);
                    // Sharp lobes amplify f32 rounding of h = normalize(wo + wi).
                    assert!(
                        (s.pdf - pdf).abs() <= 1e-2 * pdf.max(1e-3),
                        "{name}: returned pdf {} != {pdf}",
                        s.pdf
                    );
                    Some(s.wi)
                },
                |wi| ggx::reflection_pdf(wo, wi, alpha) as f64,
            );
            assert_fits(p, &name);
        }
    }
}

fn courtyard() -> EnvMap {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/envmaps/courtyard.exr");
    EnvMap::read(path).expect("the courtyard test env map")
}

#[test]
fn env_map_sampling_fits_its_pdf() {
    // 32 x 64 texels binned on an aligned 64 x 128 grid: each texel spans 2 x 2 cells.
    let env = courtyard().downsample(32);
    let sampler = EnvSampler::new(&env);
    let mut mismatches = 0;
    let p = chi2_test(
        "env map (courtyard)",
        &LatLongDomain,
        (64, 128),
        |rng| {
            let s = sampler.sample(rng.next_2d());
            // Rounding can move a sample landing on a texel edge into the neighbour: count those.
            if (s.pdf - sampler.pdf(s.direction)).abs() > 1e-3 * s.pdf {
                mismatches += 1;
            }
            Some(s.direction)
        },
        |d| sampler.pdf(d) as f64,
    );
    assert_fits(p, "env map");
    assert!(
        mismatches <= SAMPLES / 10_000,
        "{mismatches} samples whose returned pdf differs from pdf()"
    );
}

#[test]
fn env_map_pdf_follows_the_lat_long_jacobian() {
    // A constant map is sampled by solid angle: pdf = 1 / 4 pi, up to the linear interpolation of
    // the knots' sin(theta) between row centres (relative error (pi / H)^2 / 8 = 3e-4), except
    // within half a row of a pole, where the density clamps to the first row's knots.
    let env = EnvMap::constant(64, [2.0; 3]);
    let sampler = EnvSampler::new(&env);
    let mut rng = Rng::new(3, 1);
    let mut checked = 0;
    for _ in 0..1000 {
        let s = sampler.sample(rng.next_2d());
        let v = direction_to_uv(s.direction).y as f64;
        if (0.5 / 64.0..1.0 - 0.5 / 64.0).contains(&v) {
            assert!(
                (s.pdf as f64 * 4.0 * PI - 1.0).abs() < 1e-3,
                "pdf {} at {}",
                s.pdf,
                s.direction
            );
            checked += 1;
        }
    }
    assert!(checked > 950, "{checked}");
    // On a real map: sum over texels of pdf x solid angle is 1.
    let env = courtyard().downsample(64);
    let sampler = EnvSampler::new(&env);
    let total: f64 = (0..env.height())
        .flat_map(|row| (0..env.width()).map(move |col| (row, col)))
        .map(|(row, col)| {
            let d = env.texel_direction(row, col);
            // The pdf at the texel centre uses sin(theta) there; the solid angle integrates sin(theta).
            sampler.pdf(d) as f64 * env.texel_solid_angle(row) as f64
        })
        .sum();
    assert!((total - 1.0).abs() < 1e-3, "{total}");
}
