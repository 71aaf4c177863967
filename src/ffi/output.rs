//! The one place where values are cleaned for the renderer
//! (docs/conventions.md): every output goes through `out_f32`, which replaces a
//! non-finite or negative value by 0 and counts it. The models themselves must
//! never produce such values; tests assert that these counters stay 0.

use super::params::{MsxSample, MsxSpectrum, MsxVec3};
use crate::bsdf::BsdfSample;
use crate::spectrum::{Spectrum, MAX_CHANNELS};
use glam::DVec3;
use std::sync::atomic::{AtomicU64, Ordering};

static RAW_NONFINITE: AtomicU64 = AtomicU64::new(0);
static RAW_NEGATIVE: AtomicU64 = AtomicU64::new(0);
static PANICS: AtomicU64 = AtomicU64::new(0);

/// Process-wide counts of what the C ABI had to clean before returning:
/// output values that were NaN or ±Inf (including finite values that overflow
/// `float`), negative values, and panics caught at the boundary. All three
/// stay 0 unless the core has a defect; they only ever grow.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct MsxDiagnostics {
    pub nonfinite: u64,
    pub negative: u64,
    pub panics: u64,
}

/// Reads the diagnostic counters (see `MsxDiagnostics`).
#[no_mangle]
pub extern "C" fn msx_diagnostics() -> MsxDiagnostics {
    MsxDiagnostics {
        nonfinite: RAW_NONFINITE.load(Ordering::Relaxed),
        negative: RAW_NEGATIVE.load(Ordering::Relaxed),
        panics: PANICS.load(Ordering::Relaxed),
    }
}

pub(super) fn caught_panic() {
    PANICS.fetch_add(1, Ordering::Relaxed);
}

/// A value for the renderer: non-finite (after the conversion to f32) and
/// negative values become 0 and are counted.
pub(super) fn out_f32(x: f64) -> f32 {
    let y = x as f32;
    if !y.is_finite() {
        RAW_NONFINITE.fetch_add(1, Ordering::Relaxed);
        0.0
    } else if y < 0.0 {
        RAW_NEGATIVE.fetch_add(1, Ordering::Relaxed);
        0.0
    } else {
        y
    }
}

pub(super) fn out_spectrum(s: Spectrum, channels: usize) -> MsxSpectrum {
    let mut v = [0.0f32; 4];
    for (vc, &x) in v.iter_mut().zip(s.0.iter()).take(channels.min(MAX_CHANNELS)) {
        *vc = out_f32(x);
    }
    MsxSpectrum { v }
}

/// A sampled direction for the renderer, or None (counted) if not finite.
pub(super) fn out_direction(wo: DVec3) -> Option<[f32; 3]> {
    let v = [wo.x as f32, wo.y as f32, wo.z as f32];
    if v.iter().all(|x| x.is_finite()) {
        Some(v)
    } else {
        RAW_NONFINITE.fetch_add(1, Ordering::Relaxed);
        None
    }
}

/// A sample for the renderer: valid when its pdf is > 0 and its direction
/// finite; its weight cleaned like every output.
pub(super) fn out_sample(s: Option<BsdfSample>, channels: usize) -> MsxSample {
    let Some(s) = s else { return MsxSample::default() };
    let pdf = out_f32(s.pdf);
    match out_direction(s.wo) {
        Some([x, y, z]) if pdf > 0.0 => MsxSample { wo: MsxVec3 { x, y, z }, pdf, weight: out_spectrum(s.weight, channels), valid: 1 },
        _ => MsxSample::default(),
    }
}
