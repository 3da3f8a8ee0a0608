//! The one image type of gsid.
//!
//! `Image` is row-major, interleaved f32: pixel (x, y) channel c lives at
//! `data[(y * width + x) * channels + c]`, row 0 is the top row (as EXR stores it).
//! Colour is linear RGB; one-channel buffers (shadow, depth, masks) have `channels == 1`.

use rayon::prelude::*;

use crate::error::{Error, Result};

/// `n` copies of `value`, written on all threads.
///
/// Why: a buffer's pages are mapped when first written. Written inside a parallel stage loop,
/// threads that fault on the same region wait on each other: the `feature` outlier rule's 8 MB
/// table of surface-mates took 20 ms to fill on two threads against 11 ms on one. Written here
/// first, in a loop that does nothing else, the faults cost about 1 µs a page and the stage's
/// loop none.
pub(crate) fn par_vec<T: Clone + Send + Sync>(value: T, n: usize) -> Vec<T> {
    rayon::iter::repeat_n(value, n).collect()
}

#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    width: usize,
    height: usize,
    channels: usize,
    data: Vec<f32>,
}

impl Image {
    /// A zero-filled image.
    pub fn new(width: usize, height: usize, channels: usize) -> Self {
        Self::filled(width, height, channels, 0.0)
    }

    /// A copy made on all threads: a stage's output is 12 MB at 1 MP, and a serial copy (with the
    /// page faults of its fresh memory) is time the other cores wait.
    pub fn par_clone(&self) -> Self {
        let mut copy = Image::new(self.width, self.height, self.channels);
        copy.data
            .par_chunks_mut(1 << 16)
            .zip(self.data.par_chunks(1 << 16))
            .for_each(|(to, from)| to.copy_from_slice(from));
        copy
    }

    pub fn filled(width: usize, height: usize, channels: usize, value: f32) -> Self {
        Image {
            width,
            height,
            channels,
            data: par_vec(value, width * height * channels),
        }
    }

    /// Wraps interleaved data; fails if its length does not match the shape.
    pub fn from_vec(width: usize, height: usize, channels: usize, data: Vec<f32>) -> Result<Self> {
        if data.len() != width * height * channels || channels == 0 {
            return Err(Error::Usage(format!(
                "image data of length {} does not fit {width}x{height}x{channels}",
                data.len()
            )));
        }
        Ok(Image {
            width,
            height,
            channels,
            data,
        })
    }

    /// Builds an image by calling `f(x, y, c)` for every sample.
    pub fn from_fn(
        width: usize,
        height: usize,
        channels: usize,
        mut f: impl FnMut(usize, usize, usize) -> f32,
    ) -> Self {
        let mut data = Vec::with_capacity(width * height * channels);
        for y in 0..height {
            for x in 0..width {
                for c in 0..channels {
                    data.push(f(x, y, c));
                }
            }
        }
        Image {
            width,
            height,
            channels,
            data,
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    pub fn channels(&self) -> usize {
        self.channels
    }

    /// Number of pixels (not samples).
    pub fn pixel_count(&self) -> usize {
        self.width * self.height
    }

    pub fn dims(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    pub fn data(&self) -> &[f32] {
        &self.data
    }

    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }

    pub fn into_vec(self) -> Vec<f32> {
        self.data
    }

    /// The samples of pixel `i` (row-major index).
    #[inline]
    pub fn pixel(&self, i: usize) -> &[f32] {
        &self.data[i * self.channels..(i + 1) * self.channels]
    }

    #[inline]
    pub fn pixel_mut(&mut self, i: usize) -> &mut [f32] {
        &mut self.data[i * self.channels..(i + 1) * self.channels]
    }

    #[inline]
    pub fn at(&self, x: usize, y: usize) -> &[f32] {
        self.pixel(y * self.width + x)
    }

    /// Mean of each channel, accumulated in f64.
    pub fn channel_means(&self) -> Vec<f64> {
        let mut sums = vec![0.0f64; self.channels];
        for px in self.data.chunks_exact(self.channels) {
            for (s, &v) in sums.iter_mut().zip(px) {
                *s += v as f64;
            }
        }
        let n = self.pixel_count().max(1) as f64;
        sums.into_iter().map(|s| s / n).collect()
    }

    pub fn all_finite(&self) -> bool {
        self.data.iter().all(|v| v.is_finite())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn par_vec_is_n_copies_of_its_value() {
        for n in [0, 1, 7, 1 << 20] {
            assert_eq!(par_vec(0.25f32, n), vec![0.25f32; n]);
            assert_eq!(
                par_vec(([1.0f64; 3], 2usize), n),
                vec![([1.0f64; 3], 2usize); n]
            );
        }
        assert_eq!(Image::filled(3, 2, 3, 0.5).data(), &[0.5f32; 18]);
    }
}
