//! A band of rows of feature records as padded planes (structure of arrays), the layout the
//! vector kernels read 8 horizontally adjacent pixels from.

/// A band of rows of [`Features`](super::records::Features) as padded planes, for kernels that
/// compare 8 pixels at once.
pub struct FeaturePlanes {
    pub(super) first_row: usize,
    pad: usize,
    pub(super) stride: usize,
    pub(super) plane_len: usize,
    pub(super) data: Vec<f32>,
    /// Whether the material and shadow lanes (`records::MATERIAL_LANES`) may be non-zero; they are
    /// left at 0, unfilled, when not.
    pub(super) material: bool,
}

impl FeaturePlanes {
    /// Planes of `lanes` values per pixel of an image `width` wide, rows `rows`, rows padded with
    /// `pad` zero columns on both sides; `value(i, lane)` reads pixel i (row-major index).
    pub fn build(
        width: usize,
        rows: std::ops::Range<usize>,
        pad: usize,
        lanes: usize,
        value: impl Fn(usize, usize) -> f32,
    ) -> FeaturePlanes {
        let all: Vec<usize> = (0..lanes).collect();
        FeaturePlanes::build_lanes(width, rows, pad, lanes, &all, value)
    }

    /// [`FeaturePlanes::build`] with only the lanes `filled` written; the others stay 0.
    pub(super) fn build_lanes(
        width: usize,
        rows: std::ops::Range<usize>,
        pad: usize,
        lanes: usize,
        filled: &[usize],
        value: impl Fn(usize, usize) -> f32,
    ) -> FeaturePlanes {
        let mut planes = FeaturePlanes::zeroed(width, rows.clone(), pad, lanes, true);
        let (stride, plane_len) = (planes.stride, planes.plane_len);
        // Pixel by pixel, every lane of one pixel in turn: each source record is read once,
        // while its cache line is loaded, rather than once per lane.
        for (r, y) in rows.enumerate() {
            let at = r * stride + pad;
            for x in 0..width {
                for &lane in filled {
                    planes.data[lane * plane_len + at + x] = value(y * width + x, lane);
                }
            }
        }
        planes
    }

    /// Planes of `lanes` zeros per pixel for rows `rows` of an image `width` wide, every row
    /// padded by `pad` columns on both sides: the layout the builders fill.
    pub(super) fn zeroed(
        width: usize,
        rows: std::ops::Range<usize>,
        pad: usize,
        lanes: usize,
        material: bool,
    ) -> FeaturePlanes {
        let stride = width + 2 * pad;
        let plane_len = rows.len() * stride;
        FeaturePlanes {
            first_row: rows.start,
            pad,
            stride,
            plane_len,
            data: vec![0.0f32; lanes * plane_len],
            material,
        }
    }

    /// Lane `lane` of the `len` pixels starting at `offset` (see [`FeaturePlanes::offset`]).
    #[inline]
    pub fn lane(&self, lane: usize, offset: usize, len: usize) -> &[f32] {
        let start = lane * self.plane_len + offset;
        &self.data[start..start + len]
    }

    /// Where pixel (x, y) sits in every plane; x may reach `pad` columns beyond either side.
    #[inline]
    pub fn offset(&self, x: isize, y: usize) -> usize {
        (y - self.first_row) * self.stride + (x + self.pad as isize) as usize
    }
}
