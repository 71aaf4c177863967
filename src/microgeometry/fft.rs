//! Radix-2 complex FFT (iterative Cooley–Tukey), enough for the spectral
//! synthesis of height fields on power-of-two grids. Unnormalised: the
//! inverse transform is the sum Σ_k X_k e^{+2πi jk/n} without a 1/n factor.

use std::f64::consts::PI;

/// In-place transform of the complex sequence (re, im) of length n = 2^m.
/// `inverse` selects the sign + in the exponent.
pub fn fft(re: &mut [f64], im: &mut [f64], inverse: bool) {
    let n = re.len();
    assert!(n == im.len() && n.is_power_of_two(), "fft: lengths must be equal powers of two");
    if n < 2 {
        return;
    }
    // Bit-reversal permutation.
    let bits = n.trailing_zeros();
    for i in 0..n {
        let j = i.reverse_bits() >> (usize::BITS - bits);
        if j > i {
            re.swap(i, j);
            im.swap(i, j);
        }
    }
    let sign = if inverse { 1.0 } else { -1.0 };
    let mut len = 2;
    while len <= n {
        let half = len / 2;
        // Twiddles of this stage computed directly (no accumulated rotation error).
        let (tw_re, tw_im): (Vec<f64>, Vec<f64>) = (0..half)
            .map(|k| {
                let a = sign * 2.0 * PI * k as f64 / len as f64;
                (a.cos(), a.sin())
            })
            .unzip();
        for start in (0..n).step_by(len) {
            for k in 0..half {
                let (a, b) = (start + k, start + k + half);
                let (wr, wi) = (tw_re[k], tw_im[k]);
                let xr = re[b] * wr - im[b] * wi;
                let xi = re[b] * wi + im[b] * wr;
                re[b] = re[a] - xr;
                im[b] = im[a] - xi;
                re[a] += xr;
                im[a] += xi;
            }
        }
        len *= 2;
    }
}

/// In-place 2D transform of an n×n row-major array (rows, then columns).
pub fn fft2(re: &mut [f64], im: &mut [f64], n: usize, inverse: bool) {
    assert!(re.len() == n * n && im.len() == n * n);
    for row in 0..n {
        let r = row * n..(row + 1) * n;
        fft(&mut re[r.clone()], &mut im[r], inverse);
    }
    let (mut cr, mut ci) = (vec![0.0; n], vec![0.0; n]);
    for col in 0..n {
        for row in 0..n {
            cr[row] = re[row * n + col];
            ci[row] = im[row * n + col];
        }
        fft(&mut cr, &mut ci, inverse);
        for row in 0..n {
            re[row * n + col] = cr[row];
            im[row * n + col] = ci[row];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Direct O(n²) DFT with the same sign convention.
    fn dft(re: &[f64], im: &[f64], inverse: bool) -> (Vec<f64>, Vec<f64>) {
        let n = re.len();
        let sign = if inverse { 1.0 } else { -1.0 };
        (0..n)
            .map(|k| {
                (0..n).fold((0.0, 0.0), |(sr, si), j| {
                    let a = sign * 2.0 * PI * (j * k) as f64 / n as f64;
                    (sr + re[j] * a.cos() - im[j] * a.sin(), si + re[j] * a.sin() + im[j] * a.cos())
                })
            })
            .unzip()
    }

    #[test]
    fn matches_the_direct_dft_and_inverts() {
        let mut rng = crate::rng::Sampler::new(7);
        for n in [1usize, 2, 4, 8, 64] {
            let re0: Vec<f64> = (0..n).map(|_| rng.next() - 0.5).collect();
            let im0: Vec<f64> = (0..n).map(|_| rng.next() - 0.5).collect();
            for inverse in [false, true] {
                let (er, ei) = dft(&re0, &im0, inverse);
                let (mut r, mut i) = (re0.clone(), im0.clone());
                fft(&mut r, &mut i, inverse);
                for k in 0..n {
                    assert!((r[k] - er[k]).abs() < 1e-12 && (i[k] - ei[k]).abs() < 1e-12, "n={n} k={k}");
                }
            }
            // Forward then inverse returns n times the input.
            let (mut r, mut i) = (re0.clone(), im0.clone());
            fft(&mut r, &mut i, false);
            fft(&mut r, &mut i, true);
            for k in 0..n {
                assert!((r[k] / n as f64 - re0[k]).abs() < 1e-13 && (i[k] / n as f64 - im0[k]).abs() < 1e-13);
            }
        }
    }

    #[test]
    fn two_dimensional_transform_is_separable() {
        let n = 8;
        let mut rng = crate::rng::Sampler::new(3);
        let re0: Vec<f64> = (0..n * n).map(|_| rng.next() - 0.5).collect();
        let im0: Vec<f64> = (0..n * n).map(|_| rng.next() - 0.5).collect();
        let (mut r, mut i) = (re0.clone(), im0.clone());
        fft2(&mut r, &mut i, n, true);
        // Direct 2D sum at a few frequencies.
        for &(ky, kx) in &[(0usize, 0usize), (1, 3), (7, 2), (4, 4)] {
            let (mut sr, mut si) = (0.0, 0.0);
            for y in 0..n {
                for x in 0..n {
                    let a = 2.0 * PI * ((x * kx + y * ky) as f64) / n as f64;
                    let (c, s) = (a.cos(), a.sin());
                    sr += re0[y * n + x] * c - im0[y * n + x] * s;
                    si += re0[y * n + x] * s + im0[y * n + x] * c;
                }
            }
            assert!((r[ky * n + kx] - sr).abs() < 1e-12 && (i[ky * n + kx] - si).abs() < 1e-12);
        }
    }
}
