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

    #[inline]
    pub fn map(self, f: impl Fn(f64) -> f64) -> Self {
        let mut out = self.0;
        for v in &mut out {
            *v = f(*v);
        }
        Spectrum(out)
    }

    pub fn is_finite(&self) -> bool {
        self.0.iter().all(|v| v.is_finite())
    }

    /// The channels `mask` keeps, +0 in the others (bitwise: a kept value is
    /// unchanged, NaN included).
    #[inline]
    pub fn masked(self, mask: ChannelMask) -> Spectrum {
        let mut out = self.0;
        for (v, m) in out.iter_mut().zip(mask.0) {
            *v = f64::from_bits(v.to_bits() & m);
        }
        Spectrum(out)
    }
}

/// Which channels a call uses: the first `n` of [`MAX_CHANNELS`], as bit masks
/// so that [`Spectrum::masked`] zeroes the others without a branch per channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ChannelMask([u64; MAX_CHANNELS]);

impl ChannelMask {
    /// The first `n` channels (all of them for n ≥ MAX_CHANNELS).
    #[inline]
    pub fn first(n: usize) -> Self {
        const M: u64 = u64::MAX;
        const FIRST: [[u64; MAX_CHANNELS]; MAX_CHANNELS + 1] = [[0, 0, 0, 0], [M, 0, 0, 0], [M, M, 0, 0], [M, M, M, 0], [M; 4]];
        ChannelMask(FIRST[n.min(MAX_CHANNELS)])
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn masked_keeps_the_first_channels_bit_for_bit() {
        let s = Spectrum([-0.0, f64::NAN, 3.5, f64::INFINITY]);
        for n in 0..=MAX_CHANNELS + 1 {
            let m = s.masked(ChannelMask::first(n));
            for c in 0..MAX_CHANNELS {
                let want = if c < n { s.0[c].to_bits() } else { 0.0f64.to_bits() };
                assert_eq!(m.0[c].to_bits(), want, "n = {n}, channel {c}");
            }
        }
    }
}
