//! Borrowed, strided images: a renderer's framebuffer or a NumPy array as it lies in memory,
//! read or written in place of an owned [`Image`].
//!
//! A view is a slice and a [`Layout`]: where pixel (0, 0) is, and how many elements lie from a row
//! to the next, a pixel to the next and a channel to the next. Strides may be negative (a flipped
//! image, NumPy's `arr[:, ::-1]`) or leave gaps (an RGBA framebuffer read as RGB, padded rows).
//! Nothing is checked when a view is made; [`ImageView::to_image`] and [`ImageViewMut::write`]
//! check that every sample lies in the slice and say which buffer is wrong.

use crate::error::{Error, Result};
use crate::image::Image;

/// Where a view's samples lie in its slice; strides in elements (not bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    pub width: usize,
    pub height: usize,
    pub channels: usize,
    /// Index in the slice of pixel (0, 0)'s first channel.
    pub origin: usize,
    /// Elements from a row to the one below it.
    pub row_stride: isize,
    /// Elements from a pixel to the one right of it.
    pub pixel_stride: isize,
    /// Elements from a channel to the next.
    pub channel_stride: isize,
}

impl Layout {
    /// Row-major, interleaved, no gaps: what [`Image`] holds.
    pub fn packed(width: usize, height: usize, channels: usize) -> Self {
        Layout {
            width,
            height,
            channels,
            origin: 0,
            row_stride: (width * channels) as isize,
            pixel_stride: channels as isize,
            channel_stride: 1,
        }
    }

    /// A framebuffer's rows: `channels` of each pixel's `pixel_stride` elements read (RGB of
    /// RGBA: 3 of 4), rows `row_stride` elements apart (padding allowed).
    pub fn strided(
        width: usize,
        height: usize,
        channels: usize,
        row_stride: usize,
        pixel_stride: usize,
    ) -> Self {
        Layout {
            row_stride: row_stride as isize,
            pixel_stride: pixel_stride as isize,
            ..Layout::packed(width, height, channels)
        }
    }

    fn dims(&self) -> [(usize, isize); 3] {
        [
            (self.height, self.row_stride),
            (self.width, self.pixel_stride),
            (self.channels, self.channel_stride),
        ]
    }

    fn is_empty(&self) -> bool {
        self.width == 0 || self.height == 0 || self.channels == 0
    }

    /// Checks that every sample lies in a slice of `len` elements.
    fn check_in(&self, len: usize) -> std::result::Result<(), String> {
        if self.is_empty() {
            return Ok(());
        }
        let (mut lo, mut hi) = (self.origin as i128, self.origin as i128);
        for (n, stride) in self.dims() {
            let reach = (n as i128 - 1) * stride as i128;
            lo += reach.min(0);
            hi += reach.max(0);
        }
        if lo < 0 || hi >= len as i128 {
            return Err(format!(
                "a {}x{}x{} view (strides {}, {}, {} from element {}) reaches elements {lo} to {hi} of a {len}-element buffer",
                self.width,
                self.height,
                self.channels,
                self.row_stride,
                self.pixel_stride,
                self.channel_stride,
                self.origin
            ));
        }
        Ok(())
    }

    /// Checks that no two samples share an element (a written view).
    fn check_distinct(&self) -> std::result::Result<(), String> {
        let mut dims: Vec<(usize, i128)> = self
            .dims()
            .iter()
            .filter(|(n, _)| *n > 1)
            .map(|&(n, s)| (n, (s as i128).abs()))
            .collect();
        dims.sort_by_key(|&(_, s)| s);
        let mut extent = 0i128;
        for (n, s) in dims {
            if s <= extent {
                return Err(format!(
                    "strides {}, {}, {} make two samples share an element",
                    self.row_stride, self.pixel_stride, self.channel_stride
                ));
            }
            extent += s * (n as i128 - 1);
        }
        Ok(())
    }

    /// Index of sample (x, y, c); only for layouts [`Layout::check_in`] accepted.
    #[inline]
    fn index(&self, x: usize, y: usize, c: usize) -> usize {
        (self.origin as isize
            + y as isize * self.row_stride
            + x as isize * self.pixel_stride
            + c as isize * self.channel_stride) as usize
    }

    fn is_packed(&self) -> bool {
        *self
            == Layout {
                origin: self.origin,
                ..Layout::packed(self.width, self.height, self.channels)
            }
    }
}

/// The elements a raw strided image spans: `(first, count)` relative to its pixel (0, 0), or an
/// error when the shape is empty or the span does not fit the address space.
fn raw_span(
    ptr_is_null: bool,
    (width, height, channels): (usize, usize, usize),
    strides: [isize; 3],
) -> std::result::Result<(isize, usize), String> {
    if width == 0 || height == 0 || channels == 0 {
        return Err(format!(
            "is empty ({width}x{height} with {channels} channels)"
        ));
    }
    if ptr_is_null {
        return Err("is a null pointer".into());
    }
    let (mut lo, mut hi) = (0i128, 0i128);
    for (n, stride) in [height, width, channels].into_iter().zip(strides) {
        let reach = (n as i128 - 1) * stride as i128;
        lo += reach.min(0);
        hi += reach.max(0);
    }
    let count = hi - lo + 1;
    if count > (isize::MAX as i128) / 4 {
        return Err("spans more memory than exists".into());
    }
    Ok((lo as isize, count as usize))
}

/// A layout from raw strides (in elements) and the first element's place in its span.
fn raw_layout(
    (width, height, channels): (usize, usize, usize),
    strides: [isize; 3],
    first: isize,
) -> Layout {
    Layout {
        width,
        height,
        channels,
        origin: (-first) as usize,
        row_stride: strides[0],
        pixel_stride: strides[1],
        channel_stride: strides[2],
    }
}

/// A borrowed image to read.
#[derive(Clone, Copy, Debug)]
pub struct ImageView<'a> {
    data: &'a [f32],
    layout: Layout,
}

impl<'a> ImageView<'a> {
    pub fn new(data: &'a [f32], layout: Layout) -> Self {
        ImageView { data, layout }
    }

    /// Row-major, interleaved, no gaps.
    pub fn packed(data: &'a [f32], width: usize, height: usize, channels: usize) -> Self {
        Self::new(data, Layout::packed(width, height, channels))
    }

    /// A view of memory a foreign caller owns (C, NumPy): `ptr` is pixel (0, 0)'s first channel,
    /// `strides` the elements from a row, a pixel and a channel to the next (any sign). The error
    /// (an empty shape, a null pointer) is for the caller to put under the buffer's name.
    ///
    /// # Safety
    /// Every sample `ptr + y·strides[0] + x·strides[1] + c·strides[2]` and everything between
    /// the lowest and the highest of them must be readable `f32`s of one allocation, not written
    /// by anyone for `'a`.
    pub unsafe fn from_raw(
        ptr: *const f32,
        shape: (usize, usize, usize),
        strides: [isize; 3],
    ) -> std::result::Result<Self, String> {
        let (first, count) = raw_span(ptr.is_null(), shape, strides)?;
        // SAFETY: the caller vouches for the span from the lowest sample to the highest.
        let data = unsafe { std::slice::from_raw_parts(ptr.offset(first), count) };
        Ok(Self::new(data, raw_layout(shape, strides, first)))
    }

    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    pub fn dims(&self) -> (usize, usize) {
        (self.layout.width, self.layout.height)
    }

    /// A packed copy; the error names buffer `name` when a sample lies outside the slice.
    pub fn to_image(&self, name: &str) -> Result<Image> {
        let l = &self.layout;
        l.check_in(self.data.len())
            .map_err(|msg| Error::buffer(name, msg))?;
        if l.channels == 0 {
            return Err(Error::buffer(name, "has no channels"));
        }
        let n = l.width * l.height * l.channels;
        if l.is_packed() {
            return Image::from_vec(
                l.width,
                l.height,
                l.channels,
                self.data[l.origin..l.origin + n].to_vec(),
            );
        }
        Ok(Image::from_fn(l.width, l.height, l.channels, |x, y, c| {
            self.data[l.index(x, y, c)]
        }))
    }
}

/// A borrowed image to write (the caller's output buffer).
#[derive(Debug)]
pub struct ImageViewMut<'a> {
    data: &'a mut [f32],
    layout: Layout,
}

impl<'a> ImageViewMut<'a> {
    pub fn new(data: &'a mut [f32], layout: Layout) -> Self {
        ImageViewMut { data, layout }
    }

    /// Row-major, interleaved, no gaps.
    pub fn packed(data: &'a mut [f32], width: usize, height: usize, channels: usize) -> Self {
        Self::new(data, Layout::packed(width, height, channels))
    }

    /// [`ImageView::from_raw`] for writing.
    ///
    /// # Safety
    /// As [`ImageView::from_raw`], the span writable and read or written by no one else for `'a`.
    pub unsafe fn from_raw(
        ptr: *mut f32,
        shape: (usize, usize, usize),
        strides: [isize; 3],
    ) -> std::result::Result<Self, String> {
        let (first, count) = raw_span(ptr.is_null(), shape, strides)?;
        // SAFETY: the caller vouches for the span from the lowest sample to the highest.
        let data = unsafe { std::slice::from_raw_parts_mut(ptr.offset(first), count) };
        Ok(Self::new(data, raw_layout(shape, strides, first)))
    }

    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// Checks, before any work, that `image`'s shape can be written here; errors name `name`.
    pub fn check(&self, name: &str, width: usize, height: usize, channels: usize) -> Result<()> {
        let l = &self.layout;
        if (l.width, l.height, l.channels) != (width, height, channels) {
            return Err(Error::buffer(
                name,
                format!(
                    "is {}x{} with {} channels, expected {width}x{height} with {channels}",
                    l.width, l.height, l.channels
                ),
            ));
        }
        l.check_in(self.data.len())
            .and_then(|()| l.check_distinct())
            .map_err(|msg| Error::buffer(name, msg))
    }

    /// Writes `image` (of the view's shape) into the view; the elements between its samples
    /// (an alpha channel, row padding) are left as they are.
    pub fn write(&mut self, name: &str, image: &Image) -> Result<()> {
        self.check(name, image.width(), image.height(), image.channels())?;
        let l = self.layout;
        if l.is_packed() {
            let n = image.data().len();
            self.data[l.origin..l.origin + n].copy_from_slice(image.data());
            return Ok(());
        }
        for y in 0..l.height {
            for x in 0..l.width {
                for (c, &v) in image.at(x, y).iter().enumerate() {
                    self.data[l.index(x, y, c)] = v;
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strided_and_flipped_views_read_the_samples_they_name() {
        // 2x2 RGBA with a padded row of 10 elements: read as RGB.
        let data: Vec<f32> = (0..20).map(|i| i as f32).collect();
        let view = ImageView::new(&data, Layout::strided(2, 2, 3, 10, 4));
        let img = view.to_image("color").unwrap();
        assert_eq!(
            img.data(),
            &[0., 1., 2., 4., 5., 6., 10., 11., 12., 14., 15., 16.]
        );
        // The same, columns flipped (negative pixel stride from the last pixel of row 0).
        let flipped = Layout {
            origin: 4,
            pixel_stride: -4,
            ..Layout::strided(2, 2, 3, 10, 4)
        };
        let img = ImageView::new(&data, flipped).to_image("color").unwrap();
        assert_eq!(img.at(0, 1), &[14., 15., 16.]);
        assert_eq!(img.at(1, 0), &[0., 1., 2.]);
    }

    #[test]
    fn views_outside_their_slice_or_overlapping_are_refused_naming_the_buffer() {
        let data = vec![0.0; 11];
        let err = ImageView::packed(&data, 2, 2, 3).to_image("albedo");
        assert!(err
            .unwrap_err()
            .to_string()
            .starts_with("buffer `albedo`: "));
        let flipped = Layout {
            pixel_stride: -3,
            ..Layout::packed(1, 2, 3)
        };
        assert!(ImageView::new(&data, flipped).to_image("x").is_ok());
        let backwards = Layout {
            pixel_stride: -3,
            ..Layout::packed(2, 1, 3)
        };
        assert!(ImageView::new(&data, backwards).to_image("x").is_err());
        let mut out = vec![0.0; 12];
        let overlapping = Layout {
            pixel_stride: 1,
            ..Layout::packed(2, 2, 3)
        };
        let view = ImageViewMut::new(&mut out, overlapping);
        let err = view.check("out", 2, 2, 3).unwrap_err().to_string();
        assert!(err.contains("share an element"), "{err}");
    }

    #[test]
    fn a_write_leaves_the_elements_between_samples_alone() {
        let mut fb = vec![-1.0f32; 2 * 2 * 4];
        let img = Image::from_fn(2, 2, 3, |x, y, c| (y * 6 + x * 3 + c) as f32);
        ImageViewMut::new(&mut fb, Layout::strided(2, 2, 3, 8, 4))
            .write("out", &img)
            .unwrap();
        assert_eq!(
            fb,
            [0., 1., 2., -1., 3., 4., 5., -1., 6., 7., 8., -1., 9., 10., 11., -1.]
        );
    }
}
