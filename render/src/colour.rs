//! Colour: the luminance of linear Rec. 709 RGB, the one weighting of the
//! channels every part of the toolkit uses (sampling, confidence, data
//! weights, levels, PSNR peaks).

use autodiff::Real;

/// The Rec. 709 luminance weights of red, green and blue.
pub const LUMINANCE: [f64; 3] = [0.2126, 0.7152, 0.0722];

/// Luminance of linear Rec. 709 RGB, in the precision of its channels.
#[inline]
pub fn luminance<T: Real>(rgb: [T; 3]) -> T {
    T::c(LUMINANCE[0]) * rgb[0] + T::c(LUMINANCE[1]) * rgb[1] + T::c(LUMINANCE[2]) * rgb[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_sum_to_one_and_are_the_same_in_f32() {
        assert!((LUMINANCE.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert_eq!(luminance([1.0f64, 1.0, 1.0]), 1.0);
        // The f32 weights are the nearest f32 to each decimal weight.
        assert_eq!(LUMINANCE.map(|w| w as f32), [0.2126f32, 0.7152, 0.0722]);
        assert_eq!(luminance([0.0f32, 1.0, 0.0]), 0.7152f32);
    }
}
