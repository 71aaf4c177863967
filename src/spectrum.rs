//! Per-channel values: up to four channels per call (RGB uses 3, Mitsuba's
//! spectral variants sample 4 wavelengths). Unused channels are carried along.

use std::ops::{Add, AddAssign, Mul, MulAssign};

pub const MAX_CHANNELS: usize = 4;

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spectrum(pub [f64; MAX_CHANNELS]);

impl Spectrum {
    pub const ZERO: Spectrum = Spectrum([0.0; MAX_CHANNELS]);
    pub const ONE: Spectrum = Spectrum([1.0; MAX_CHANNELS]);

    pub fn splat(v: f64) -> Self {
        Spectrum([v; MAX_CHANNELS])
    }

    pub fn max_value(&self) -> f64 {
        self.0.iter().copied().fold(0.0, f64::max)
    }

    pub fn map(self, f: impl Fn(f64) -> f64) -> Self {
        Spectrum(self.0.map(f))
    }

    pub fn is_finite(&self) -> bool {
        self.0.iter().all(|v| v.is_finite())
    }
}

impl Default for Spectrum {
    fn default() -> Self {
        Spectrum::ZERO
    }
}

impl Add for Spectrum {
    type Output = Spectrum;
    fn add(self, o: Spectrum) -> Spectrum {
        Spectrum(std::array::from_fn(|i| self.0[i] + o.0[i]))
    }
}

impl AddAssign for Spectrum {
    fn add_assign(&mut self, o: Spectrum) {
        *self = *self + o;
    }
}

impl Mul for Spectrum {
    type Output = Spectrum;
    fn mul(self, o: Spectrum) -> Spectrum {
        Spectrum(std::array::from_fn(|i| self.0[i] * o.0[i]))
    }
}

impl MulAssign for Spectrum {
    fn mul_assign(&mut self, o: Spectrum) {
        *self = *self * o;
    }
}

impl Mul<f64> for Spectrum {
    type Output = Spectrum;
    fn mul(self, s: f64) -> Spectrum {
        self.map(|v| v * s)
    }
}

impl MulAssign<f64> for Spectrum {
    fn mul_assign(&mut self, s: f64) {
        *self = *self * s;
    }
}
