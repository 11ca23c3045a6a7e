//! Image error metrics on float AO buffers (values nominally in `[0, 1]`,
//! row-major, one value a pixel): [`rmse`], [`psnr`], [`ssim`] and the
//! per-pixel [`error_map`].
//!
//! Every metric works on the `f32` values directly, in `f64` arithmetic.
//! We do not use the `image-compare` crate: it works on 8-bit images, and
//! quantizing AO to 256 levels would hide the small differences these
//! metrics are meant to measure.

use thiserror::Error;

/// Why two images could not be compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Error)]
#[non_exhaustive]
pub enum MetricError {
    /// The two images differ in length.
    #[error("reference has {reference} pixels but test has {test}")]
    LengthMismatch {
        /// Pixels of the reference.
        reference: usize,
        /// Pixels of the test image.
        test: usize,
    },
    /// `width * height` is not the number of pixels.
    #[error("{width} x {height} image does not match {len} pixels")]
    SizeMismatch {
        /// The given width.
        width: usize,
        /// The given height.
        height: usize,
        /// The number of pixels of the images.
        len: usize,
    },
    /// The images have no pixels.
    #[error("the images are empty")]
    Empty,
    /// A pixel is NaN or infinite (in either image).
    #[error("pixel {index} is not finite")]
    NonFinite {
        /// Index of the first pixel that is not finite in either image.
        index: usize,
    },
}

/// Checks equal lengths, at least one pixel and finite values.
fn check(reference: &[f32], test: &[f32]) -> Result<(), MetricError> {
    if reference.len() != test.len() {
        return Err(MetricError::LengthMismatch {
            reference: reference.len(),
            test: test.len(),
        });
    }
    if reference.is_empty() {
        return Err(MetricError::Empty);
    }
    match reference
        .iter()
        .zip(test)
        .position(|(a, b)| !a.is_finite() || !b.is_finite())
    {
        Some(index) => Err(MetricError::NonFinite { index }),
        None => Ok(()),
    }
}

/// Mean squared error, after [`check`].
fn mse(reference: &[f32], test: &[f32]) -> f64 {
    let sum: f64 = reference
        .iter()
        .zip(test)
        .map(|(&a, &b)| {
            let d = a as f64 - b as f64;
            d * d
        })
        .sum();
    sum / reference.len() as f64
}

/// Root mean squared error between two images of the same length.
///
/// Errors: [`MetricError::LengthMismatch`], [`MetricError::Empty`],
/// [`MetricError::NonFinite`].
pub fn rmse(reference: &[f32], test: &[f32]) -> Result<f64, MetricError> {
    check(reference, test)?;
    Ok(mse(reference, test).sqrt())
}

/// Peak signal-to-noise ratio in dB with a peak of 1.0:
/// `10 log10(1 / MSE)`. Identical images give `f64::INFINITY`.
///
/// Errors: as [`rmse`].
pub fn psnr(reference: &[f32], test: &[f32]) -> Result<f64, MetricError> {
    check(reference, test)?;
    let mse = mse(reference, test);
    if mse == 0.0 {
        Ok(f64::INFINITY)
    } else {
        Ok(10.0 * (1.0 / mse).log10())
    }
}

/// Side of the SSIM window (Wang et al. 2004).
const SSIM_WINDOW: usize = 11;
/// Standard deviation of the SSIM Gaussian window, pixels.
const SSIM_SIGMA: f64 = 1.5;
/// SSIM constant K1.
const SSIM_K1: f64 = 0.01;
/// SSIM constant K2.
const SSIM_K2: f64 = 0.03;
/// Dynamic range of the values.
const SSIM_RANGE: f64 = 1.0;

/// Normalized 1D Gaussian weights of an odd window `size`.
fn gaussian_window(size: usize) -> Vec<f64> {
    let centre = (size / 2) as f64;
    let w: Vec<f64> = (0..size)
        .map(|i| {
            let t = i as f64 - centre;
            (-t * t / (2.0 * SSIM_SIGMA * SSIM_SIGMA)).exp()
        })
        .collect();
    let total: f64 = w.iter().sum();
    w.into_iter().map(|x| x / total).collect()
}

/// Separable "valid" filtering of a `width x height` image with the 1D
/// `kernel`: the result is `(width - k + 1) x (height - k + 1)`.
fn filter_valid(img: &[f64], width: usize, height: usize, kernel: &[f64]) -> Vec<f64> {
    let k = kernel.len();
    let ow = width + 1 - k;
    let oh = height + 1 - k;
    let mut rows = vec![0.0; ow * height];
    for y in 0..height {
        let src = &img[y * width..(y + 1) * width];
        for x in 0..ow {
            rows[y * ow + x] = kernel.iter().zip(&src[x..x + k]).map(|(w, v)| w * v).sum();
        }
    }
    let mut out = vec![0.0; ow * oh];
    for y in 0..oh {
        for x in 0..ow {
            out[y * ow + x] = kernel
                .iter()
                .enumerate()
                .map(|(j, w)| w * rows[(y + j) * ow + x])
                .sum();
        }
    }
    out
}

/// Structural similarity (Wang, Bovik, Sheikh and Simoncelli 2004) of two
/// `width x height` row-major images: an 11 x 11 Gaussian window with
/// standard deviation 1.5, `K1 = 0.01`, `K2 = 0.03` and a dynamic range
/// `L = 1`, averaged over every position where the window lies inside the
/// image (no padding). An image narrower or shorter than 11 pixels uses
/// the largest odd window that fits (1 x 1 for a one-pixel side), with the
/// same standard deviation and the weights renormalized.
///
/// Computed on the float values (no 8-bit quantization, unlike the
/// `image-compare` crate). Identical images give 1; the result is
/// symmetric in its arguments.
///
/// Errors: as [`rmse`], and [`MetricError::SizeMismatch`] when
/// `width * height` is not the images' length.
pub fn ssim(
    reference: &[f32],
    test: &[f32],
    width: usize,
    height: usize,
) -> Result<f64, MetricError> {
    if reference.len() != test.len() {
        return Err(MetricError::LengthMismatch {
            reference: reference.len(),
            test: test.len(),
        });
    }
    if reference.is_empty() {
        return Err(MetricError::Empty);
    }
    if width.checked_mul(height) != Some(reference.len()) {
        return Err(MetricError::SizeMismatch {
            width,
            height,
            len: reference.len(),
        });
    }
    check(reference, test)?;

    let side = width.min(height);
    let size = if side >= SSIM_WINDOW {
        SSIM_WINDOW
    } else if side % 2 == 1 {
        side
    } else {
        side - 1
    };
    let kernel = gaussian_window(size);
    let x: Vec<f64> = reference.iter().map(|&v| v as f64).collect();
    let y: Vec<f64> = test.iter().map(|&v| v as f64).collect();
    let xx: Vec<f64> = x.iter().map(|v| v * v).collect();
    let yy: Vec<f64> = y.iter().map(|v| v * v).collect();
    let xy: Vec<f64> = x.iter().zip(&y).map(|(a, b)| a * b).collect();
    let mu_x = filter_valid(&x, width, height, &kernel);
    let mu_y = filter_valid(&y, width, height, &kernel);
    let e_xx = filter_valid(&xx, width, height, &kernel);
    let e_yy = filter_valid(&yy, width, height, &kernel);
    let e_xy = filter_valid(&xy, width, height, &kernel);

    let c1 = (SSIM_K1 * SSIM_RANGE).powi(2);
    let c2 = (SSIM_K2 * SSIM_RANGE).powi(2);
    let n = mu_x.len();
    let total: f64 = (0..n)
        .map(|i| {
            let (mx, my) = (mu_x[i], mu_y[i]);
            let var_x = e_xx[i] - mx * mx;
            let var_y = e_yy[i] - my * my;
            let cov = e_xy[i] - mx * my;
            ((2.0 * mx * my + c1) * (2.0 * cov + c2))
                / ((mx * mx + my * my + c1) * (var_x + var_y + c2))
        })
        .sum();
    Ok(total / n as f64)
}

/// Absolute difference per pixel, `|reference - test|`. Only the pixels
/// both images have are compared (the result has the shorter length); a
/// NaN in either image gives NaN at that pixel.
pub fn error_map(reference: &[f32], test: &[f32]) -> Vec<f32> {
    reference
        .iter()
        .zip(test)
        .map(|(a, b)| (a - b).abs())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth test image with structure, values in [0.1, 0.9].
    fn pattern(width: usize, height: usize) -> Vec<f32> {
        (0..width * height)
            .map(|i| {
                let (x, y) = ((i % width) as f32, (i / width) as f32);
                0.5 + 0.25 * (x * 0.3).sin() + 0.15 * (y * 0.2).cos()
            })
            .collect()
    }

    /// Deterministic noise in [-amp, amp] (a 64-bit LCG).
    fn noisy(img: &[f32], amp: f32, seed: u64) -> Vec<f32> {
        let mut s = seed;
        img.iter()
            .map(|&v| {
                s = s
                    .wrapping_mul(6_364_136_223_846_793_005)
                    .wrapping_add(1_442_695_040_888_963_407);
                let u = (s >> 40) as f32 / (1u64 << 24) as f32;
                v + amp * (2.0 * u - 1.0)
            })
            .collect()
    }

    #[test]
    fn identical_images() {
        let a = pattern(32, 24);
        assert_eq!(rmse(&a, &a).unwrap(), 0.0);
        assert_eq!(psnr(&a, &a).unwrap(), f64::INFINITY);
        assert!((ssim(&a, &a, 32, 24).unwrap() - 1.0).abs() < 1e-12);
        assert!(error_map(&a, &a).iter().all(|&e| e == 0.0));
    }

    #[test]
    fn constant_offset() {
        let a = pattern(20, 20);
        let b: Vec<f32> = a.iter().map(|v| v + 0.1).collect();
        assert!((rmse(&a, &b).unwrap() - 0.1).abs() < 1e-6);
        assert!((psnr(&a, &b).unwrap() - 20.0).abs() < 1e-4);
        let map = error_map(&a, &b);
        assert_eq!(map.len(), a.len());
        assert!(map.iter().all(|e| (e - 0.1).abs() < 1e-6));
    }

    #[test]
    fn known_rmse() {
        // Errors 0, 0.2, 0, 0.4: MSE = 0.05.
        let a = [0.0, 0.5, 1.0, 0.5];
        let b = [0.0, 0.7, 1.0, 0.1];
        assert!((rmse(&a, &b).unwrap() - 0.05f64.sqrt()).abs() < 1e-7);
        assert!((psnr(&a, &b).unwrap() - 10.0 * 20f64.log10()).abs() < 1e-5);
        let map = error_map(&a, &b);
        assert!((map[1] - 0.2).abs() < 1e-6 && (map[3] - 0.4).abs() < 1e-6);
    }

    #[test]
    fn ssim_orders_noise_levels() {
        let (w, h) = (48, 40);
        let a = pattern(w, h);
        let slight = noisy(&a, 0.05, 1);
        let heavy = noisy(&a, 0.3, 2);
        let s1 = ssim(&a, &slight, w, h).unwrap();
        let s2 = ssim(&a, &heavy, w, h).unwrap();
        assert!(s1 < 1.0, "{s1}");
        assert!(s1 > s2, "{s1} <= {s2}");
        assert!(s2 > -1.0);
    }

    #[test]
    fn ssim_is_symmetric() {
        let (w, h) = (30, 17);
        let a = pattern(w, h);
        let b = noisy(&a, 0.2, 7);
        assert_eq!(ssim(&a, &b, w, h).unwrap(), ssim(&b, &a, w, h).unwrap());
    }

    #[test]
    fn ssim_small_images_use_a_smaller_window() {
        // 6 x 4: a 3 x 3 window, 4 x 2 positions.
        let a = pattern(6, 4);
        let b = noisy(&a, 0.2, 3);
        let s = ssim(&a, &b, 6, 4).unwrap();
        assert!(s.is_finite() && s < 1.0);
        assert!((ssim(&a, &a, 6, 4).unwrap() - 1.0).abs() < 1e-12);
        // One pixel: the window is 1 x 1.
        let one = ssim(&[0.5], &[0.5], 1, 1).unwrap();
        assert!((one - 1.0).abs() < 1e-12);
        assert!(ssim(&[0.5], &[0.2], 1, 1).unwrap() < 1.0);
    }

    #[test]
    fn ssim_of_a_contrast_inversion_is_negative() {
        let (w, h) = (24, 24);
        let a = pattern(w, h);
        let inv: Vec<f32> = a.iter().map(|v| 1.0 - v).collect();
        assert!(ssim(&a, &inv, w, h).unwrap() < 0.0);
    }

    #[test]
    fn errors() {
        let a = [0.1f32, 0.2, 0.3, 0.4];
        assert_eq!(
            rmse(&a, &a[..3]),
            Err(MetricError::LengthMismatch {
                reference: 4,
                test: 3
            })
        );
        assert!(matches!(
            psnr(&a[..2], &a),
            Err(MetricError::LengthMismatch { .. })
        ));
        assert!(matches!(
            ssim(&a, &a[..1], 2, 2),
            Err(MetricError::LengthMismatch { .. })
        ));
        assert_eq!(rmse(&[], &[]), Err(MetricError::Empty));
        assert_eq!(psnr(&[], &[]), Err(MetricError::Empty));
        assert_eq!(ssim(&[], &[], 0, 0), Err(MetricError::Empty));
        assert_eq!(
            ssim(&a, &a, 3, 2),
            Err(MetricError::SizeMismatch {
                width: 3,
                height: 2,
                len: 4
            })
        );
        assert!(matches!(
            ssim(&a, &a, usize::MAX, 2),
            Err(MetricError::SizeMismatch { .. })
        ));
        let nan = [0.1f32, 0.2, f32::NAN, 0.4];
        let inf = [0.1f32, f32::INFINITY, 0.3, 0.4];
        assert_eq!(rmse(&a, &nan), Err(MetricError::NonFinite { index: 2 }));
        assert_eq!(psnr(&nan, &a), Err(MetricError::NonFinite { index: 2 }));
        assert_eq!(
            ssim(&nan, &inf, 2, 2),
            Err(MetricError::NonFinite { index: 1 })
        );
        assert!(error_map(&a, &nan)[2].is_nan());
        assert_eq!(error_map(&a, &a[..3]).len(), 3);
    }
}
