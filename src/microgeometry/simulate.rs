//! Light transport on explicit microgeometry: a collimated beam falls on
//! generated Beckmann surfaces and every ray is followed through all its
//! bounces until it leaves (upward: reflected; downward into a dielectric:
//! transmitted). Facets scatter like the microsurfaces of Heitz et al. 2016:
//!
//! * conductor: mirror reflection, weight × Fresnel F(ω·m) (F = 1 for η = 0, k = 1);
//! * dielectric (relative IOR η = η_int/η_ext): reflection with probability F,
//!   otherwise refraction (total internal reflection where F = 1); rays in the
//!   material travel below the surface and leave downward;
//! * diffuse: Lambertian facets, cosine-distributed about the facet normal,
//!   weight × albedo.
//!
//! The beam enters through the plane above the highest vertex at a uniform
//! position over one period (uniform irradiance of the macro surface), so the
//! weight a ray carries out is its share of the incident flux: the tallies are
//! flux fractions, per scattering order (number of facet events) and per
//! outgoing direction bin. Lobe values dE/dω therefore compare with
//! f(ω_i, ω_o)·|cos θ_o| of a BSDF in Mitsuba's Importance mode.
//!
//! Each independent surface realisation is one batch: its rays' tallies are
//! kept apart so that the spread between batches measures the whole Monte
//! Carlo error, finite surface included (docs/microgeometry.md).

use super::surface::{HeightField, SurfaceParams};
use super::trace::{Side, Trace};
use crate::microfacet::{fresnel, reflect, refract};
use crate::rng::{hash_words, Sampler};
use glam::DVec3;
use std::f64::consts::PI;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Orders tallied separately: 1, 2, 3 and 4+ (the last bin collects the rest).
pub(crate) const ORDERS: usize = 4;

/// What a facet does to light.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Facet {
    /// Complex IOR η + ik; η = 0, k = 1 is the perfect mirror (F = 1).
    Conductor { eta: f64, k: f64 },
    /// Relative IOR η_int/η_ext.
    Dielectric { ior: f64 },
    /// Lambertian facets.
    Diffuse { albedo: f64 },
}

#[derive(Clone, Copy, Debug)]
pub struct SimConfig {
    pub surface: SurfaceParams,
    pub facet: Facet,
    /// Direction towards the light: polar angle in [0, π/2), azimuth.
    pub theta_i: f64,
    pub phi_i: f64,
    /// Independent surface realisations (batches), ≥ 2.
    pub surfaces: usize,
    pub seed: u64,
    /// Direction bins: θ_o uniform over [0, π], φ_o uniform over 2π with bin 0
    /// centred on φ_i.
    pub theta_bins: usize,
    pub phi_bins: usize,
    /// Rays still bouncing after this many facet events are dropped (counted).
    pub max_bounces: u32,
}

impl SimConfig {
    pub fn validate(&self) -> Result<(), String> {
        self.surface.validate()?;
        match self.facet {
            Facet::Conductor { eta, k } if !(eta.is_finite() && k.is_finite() && eta >= 0.0 && k >= 0.0 && eta + k > 0.0) => {
                return Err(format!("conductor eta, k must be finite, ≥ 0 and not both 0, got ({eta}, {k})"))
            }
            Facet::Dielectric { ior } if !(ior.is_finite() && ior > 0.0 && ior != 1.0) => {
                return Err(format!("dielectric ior must be finite, > 0 and ≠ 1, got {ior}"))
            }
            Facet::Diffuse { albedo } if !(albedo.is_finite() && (0.0..=1.0).contains(&albedo)) => {
                return Err(format!("diffuse albedo must lie in [0, 1], got {albedo}"))
            }
            _ => {}
        }
        if !(self.theta_i.is_finite() && (0.0..PI / 2.0).contains(&self.theta_i)) {
            return Err(format!("theta_i must lie in [0, π/2), got {}", self.theta_i));
        }
        if !self.phi_i.is_finite() {
            return Err("phi_i must be finite".into());
        }
        if !(2..=4096).contains(&self.surfaces) {
            return Err(format!("surfaces must be 2..=4096, got {}", self.surfaces));
        }
        if !(1..=4096).contains(&self.theta_bins) || !(1..=4096).contains(&self.phi_bins) {
            return Err(format!("theta_bins and phi_bins must be 1..=4096, got {} and {}", self.theta_bins, self.phi_bins));
        }
        if !(1..=1_000_000).contains(&self.max_bounces) {
            return Err(format!("max_bounces must be 1..=1000000, got {}", self.max_bounces));
        }
        Ok(())
    }

    /// Unit direction towards the light.
    pub fn wi(&self) -> DVec3 {
        let (st, ct) = self.theta_i.sin_cos();
        let (sp, cp) = self.phi_i.sin_cos();
        DVec3::new(st * cp, st * sp, ct)
    }

    pub fn bins(&self) -> usize {
        self.theta_bins * self.phi_bins
    }

    /// Direction bin of an outgoing direction.
    #[inline]
    pub fn bin_of(&self, w: DVec3) -> usize {
        let theta = w.z.clamp(-1.0, 1.0).acos();
        let it = ((theta / PI * self.theta_bins as f64) as usize).min(self.theta_bins - 1);
        let dphi = 2.0 * PI / self.phi_bins as f64;
        let phi = w.y.atan2(w.x) - self.phi_i;
        let ip = ((phi / dphi + 0.5).floor() as i64).rem_euclid(self.phi_bins as i64) as usize;
        it * self.phi_bins + ip
    }
}

/// Per-batch sums (each batch = one surface realisation).
#[derive(Clone, Debug)]
pub struct Tally {
    pub surfaces: usize,
    pub bins: usize,
    /// Σ weight per [surface][order][bin] (bin = θ index · phi_bins + φ index).
    pub lobes: Vec<f64>,
    /// Σ weight per [surface][order][0 = reflected (up), 1 = transmitted (down)].
    pub energy: Vec<f64>,
    /// Rays traced per surface (lost and capped ones included).
    pub rays: Vec<u64>,
    /// Rays that failed numerically ([`Trace::Lost`]), per surface.
    pub lost: Vec<u64>,
    /// Rays dropped at `max_bounces`, per surface.
    pub capped: Vec<u64>,
    /// Σ bounces of the rays that left, per surface.
    pub bounces: Vec<u64>,
}

impl Tally {
    fn new(surfaces: usize, bins: usize) -> Tally {
        Tally {
            surfaces,
            bins,
            lobes: vec![0.0; surfaces * ORDERS * bins],
            energy: vec![0.0; surfaces * ORDERS * 2],
            rays: vec![0; surfaces],
            lost: vec![0; surfaces],
            capped: vec![0; surfaces],
            bounces: vec![0; surfaces],
        }
    }

    fn add(&mut self, o: &Tally) {
        let add = |a: &mut [f64], b: &[f64]| a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        let addu = |a: &mut [u64], b: &[u64]| a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        add(&mut self.lobes, &o.lobes);
        add(&mut self.energy, &o.energy);
        addu(&mut self.rays, &o.rays);
        addu(&mut self.lost, &o.lost);
        addu(&mut self.capped, &o.capped);
        addu(&mut self.bounces, &o.bounces);
    }
}

/// How one ray ended.
#[derive(Clone, Copy, Debug)]
pub enum RayOutcome {
    /// Left the surface along `dir` after `bounces` facet events with `weight`.
    Left {
        dir: DVec3,
        weight: f64,
        bounces: u32,
    },
    Lost,
    Capped,
}

/// Cosine-distributed direction about the unit vector n.
fn cosine_about(n: DVec3, u1: f64, u2: f64) -> DVec3 {
    let r = u1.sqrt();
    let (s, c) = (2.0 * PI * u2).sin_cos();
    let z = (1.0 - u1).max(0.0).sqrt();
    // Orthonormal basis about n (Duff et al. 2017).
    let sign = if n.z >= 0.0 { 1.0 } else { -1.0 };
    let a = -1.0 / (sign + n.z);
    let b = n.x * n.y * a;
    let t = DVec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
    let bt = DVec3::new(b, sign + n.y * n.y * a, -n.y);
    (t * (r * c) + bt * (r * s) + n * z).normalize()
}

/// Follows one ray entering from above at (x, y) (physical units, any value:
/// the surface is periodic) travelling along −ω_i.
pub fn trace_ray(field: &HeightField, facet: Facet, wi: DVec3, x: f64, y: f64, max_bounces: u32, rng: &mut Sampler) -> RayOutcome {
    let mut pos = DVec3::new(x, y, field.zmax + 1e-6 * (1.0 + field.zmax.abs()));
    let mut dir = -wi;
    let mut side = Side::Outside;
    let mut skip = None;
    let mut weight = 1.0;
    let mut bounces = 0u32;
    loop {
        match field.trace(pos, dir, side, skip) {
            Trace::Escape => return RayOutcome::Left { dir, weight, bounces },
            Trace::Lost => return RayOutcome::Lost,
            Trace::Hit { pos: p, tri, normal } => {
                if bounces == max_bounces {
                    return RayOutcome::Capped;
                }
                bounces += 1;
                pos = p;
                skip = Some(tri);
                let w = -dir;
                let cos_i = w.dot(normal);
                match facet {
                    Facet::Conductor { eta, k } => {
                        if !(eta == 0.0 && k == 1.0) {
                            weight *= fresnel::conductor(cos_i, eta, k);
                        }
                        dir = reflect(w, normal);
                    }
                    Facet::Dielectric { ior } => {
                        // cos_i > 0 from the outside (the normal points out).
                        let (f, cos_t, _, eta_ti) = fresnel::dielectric_full(cos_i, ior);
                        if rng.next() < f {
                            dir = reflect(w, normal);
                        } else {
                            dir = refract(w, normal, cos_t, eta_ti);
                            side = if side == Side::Outside { Side::Inside } else { Side::Outside };
                        }
                    }
                    Facet::Diffuse { albedo } => {
                        weight *= albedo;
                        let (u1, u2) = rng.next2();
                        dir = cosine_about(normal, u1, u2);
                    }
                }
                let len = dir.length();
                if !(len > 0.0 && len.is_finite()) {
                    return RayOutcome::Lost;
                }
                dir /= len;
            }
        }
    }
}

/// A simulation: the surfaces of one configuration and the tallies so far.
pub struct Simulation {
    cfg: SimConfig,
    fields: Vec<HeightField>,
    tally: Tally,
    /// Rays traced so far on each surface.
    done: u64,
}

/// Rays per work item of the thread pool.
const CHUNK: u64 = 2048;

impl Simulation {
    /// Generates the surfaces (independent realisations from `seed`).
    pub fn new(cfg: SimConfig) -> Result<Simulation, String> {
        cfg.validate()?;
        let mut fields = Vec::with_capacity(cfg.surfaces);
        let mut pair = 0u64;
        while fields.len() < cfg.surfaces {
            let [a, b] = HeightField::generate_pair(&cfg.surface, hash_words(&[cfg.seed, pair]))?;
            fields.push(a);
            if fields.len() < cfg.surfaces {
                fields.push(b);
            }
            pair += 1;
        }
        let tally = Tally::new(cfg.surfaces, cfg.bins());
        Ok(Simulation { cfg, fields, tally, done: 0 })
    }

    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    pub fn fields(&self) -> &[HeightField] {
        &self.fields
    }

    pub fn tally(&self) -> &Tally {
        &self.tally
    }

    /// Traces `rays_per_surface` more rays on every surface with `threads`
    /// threads. Ray j of surface s always uses the same random numbers, so the
    /// result does not depend on the thread count or on how the rays are split
    /// between calls.
    pub fn run(&mut self, rays_per_surface: u64, threads: usize) {
        let cfg = self.cfg;
        let start = self.done;
        let items: Vec<(usize, u64, u64)> = (0..cfg.surfaces)
            .flat_map(|s| (0..rays_per_surface.div_ceil(CHUNK)).map(move |c| (s, start + c * CHUNK, start + ((c + 1) * CHUNK).min(rays_per_surface))))
            .collect();
        let next = AtomicUsize::new(0);
        let fields = &self.fields;
        let worker = || {
            let mut local = Tally::new(cfg.surfaces, cfg.bins());
            let wi = cfg.wi();
            loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(&(s, r0, r1)) = items.get(i) else { break };
                let field = &fields[s];
                let (px, py) = field.period();
                for r in r0..r1 {
                    let mut rng = Sampler::new(hash_words(&[cfg.seed, 0x7261_7973, s as u64, r]));
                    let (x, y) = (rng.next() * px, rng.next() * py);
                    local.rays[s] += 1;
                    match trace_ray(field, cfg.facet, wi, x, y, cfg.max_bounces, &mut rng) {
                        RayOutcome::Left { dir, weight, bounces } => {
                            let order = (bounces.max(1) as usize).min(ORDERS) - 1;
                            let bin = cfg.bin_of(dir);
                            local.lobes[(s * ORDERS + order) * cfg.bins() + bin] += weight;
                            local.energy[(s * ORDERS + order) * 2 + usize::from(dir.z < 0.0)] += weight;
                            local.bounces[s] += bounces as u64;
                        }
                        RayOutcome::Lost => local.lost[s] += 1,
                        RayOutcome::Capped => local.capped[s] += 1,
                    }
                }
            }
            local
        };
        let threads = threads.clamp(1, items.len().max(1));
        let locals: Vec<Tally> = if threads == 1 {
            vec![worker()]
        } else {
            std::thread::scope(|sc| {
                let handles: Vec<_> = (0..threads).map(|_| sc.spawn(worker)).collect();
                handles.into_iter().map(|h| h.join().expect("simulation worker panicked")).collect()
            })
        };
        for l in &locals {
            self.tally.add(l);
        }
        self.done += rays_per_surface;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(facet: Facet) -> SimConfig {
        SimConfig {
            surface: SurfaceParams { alpha_x: 0.6, alpha_y: 0.6, grid: 64, corr_cells: 4.0 },
            facet,
            theta_i: 0.7,
            phi_i: 0.3,
            surfaces: 2,
            seed: 1,
            theta_bins: 18,
            phi_bins: 12,
            max_bounces: 1000,
        }
    }

    #[test]
    fn lossless_facets_conserve_every_ray() {
        for facet in [Facet::Conductor { eta: 0.0, k: 1.0 }, Facet::Dielectric { ior: 1.5 }, Facet::Diffuse { albedo: 1.0 }] {
            let mut sim = Simulation::new(cfg(facet)).unwrap();
            sim.run(3000, 2);
            let t = sim.tally();
            let rays: u64 = t.rays.iter().sum();
            let lost: u64 = t.lost.iter().sum::<u64>() + t.capped.iter().sum::<u64>();
            let energy: f64 = t.energy.iter().sum();
            let lobes: f64 = t.lobes.iter().sum();
            assert_eq!(rays, 6000);
            assert_eq!(lost, 0, "{facet:?}");
            assert!((energy - 6000.0).abs() < 1e-6 && (lobes - energy).abs() < 1e-6, "{facet:?}: {energy} {lobes}");
            if let Facet::Conductor { .. } | Facet::Diffuse { .. } = facet {
                let down: f64 = (0..2 * ORDERS).map(|i| t.energy[i * 2 + 1]).sum();
                assert_eq!(down, 0.0);
            }
        }
    }

    #[test]
    fn results_do_not_depend_on_threads_or_chunking() {
        let facet = Facet::Dielectric { ior: 1.5 };
        let mut a = Simulation::new(cfg(facet)).unwrap();
        a.run(5000, 1);
        let mut b = Simulation::new(cfg(facet)).unwrap();
        b.run(1234, 2);
        b.run(5000 - 1234, 3);
        assert_eq!(a.tally().lobes, b.tally().lobes);
        assert_eq!(a.tally().energy, b.tally().energy);
    }

    #[test]
    fn direction_bins_are_centred_on_the_incident_azimuth() {
        let c = cfg(Facet::Diffuse { albedo: 1.0 });
        let dphi = 2.0 * PI / 12.0;
        let w = |t: f64, p: f64| DVec3::new(t.sin() * p.cos(), t.sin() * p.sin(), t.cos());
        assert_eq!(c.bin_of(w(0.5, 0.3 + 0.49 * dphi)) % 12, 0);
        assert_eq!(c.bin_of(w(0.5, 0.3 - 0.49 * dphi)) % 12, 0);
        assert_eq!(c.bin_of(w(0.5, 0.3 + PI)) % 12, 6);
        assert_eq!(c.bin_of(w(PI - 1e-9, 0.0)) / 12, 17);
        assert_eq!(c.bin_of(w(1e-9, 0.0)) / 12, 0);
    }
}
