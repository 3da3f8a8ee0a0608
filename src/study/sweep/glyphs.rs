//! plotters' bitmap backend with text drawn by ab_glyph, working around plotters' bitmap text bugs.
//!
//! plotters 0.3.7 rasterises ab_glyph text without each glyph's left side bearing, so `walks=10`
//! comes out as `walks=1 0` in the PNG (the SVG backend writes `<text>` and is not affected). Related
//! reports of its ab_glyph text layout: <https://github.com/plotters-rs/plotters/issues/576> (spaces
//! between words lost) and <https://github.com/plotters-rs/plotters/issues/572> (text misplaced in
//! PNG output). Once plotters lays out glyphs with their bearings, this file can go.

use plotters::prelude::*;
use plotters_backend as pb;
use plotters_backend::text_anchor::{HPos, VPos};

use crate::error::{Error, Result};

/// plotters' bitmap backend with its text drawn correctly.
///
/// plotters 0.3.7 draws ab_glyph text without each glyph's left side bearing (`walks=10` comes out as
/// `walks=1 0`), and only the bitmap is affected: the SVG backend writes `<text>` for the viewer to
/// set. This wrapper passes everything to the bitmap backend except text, which it lays out and
/// rasterises itself with ab_glyph from the embedded font (kerning, bearings, anchors, rotations).
pub struct GlyphBitmap<'a> {
    inner: BitMapBackend<'a>,
    font: ab_glyph::FontRef<'static>,
}

type BitmapError<'a> = pb::DrawingErrorKind<<BitMapBackend<'a> as DrawingBackend>::ErrorType>;

impl<'a> GlyphBitmap<'a> {
    pub fn new(inner: BitMapBackend<'a>, font: &'static [u8]) -> Result<Self> {
        let font = ab_glyph::FontRef::try_from_slice(font)
            .map_err(|e| Error::Runtime(format!("the embedded plot font does not load: {e}")))?;
        Ok(GlyphBitmap { inner, font })
    }

    /// Calls `f(x, y, coverage)` for every pixel of `text` at `size` px, with the layout box's top left
    /// at (0, 0) and the baseline at the font's ascent; returns the box's width and height.
    fn layout(&self, text: &str, size: f64, mut f: impl FnMut(i32, i32, f32)) -> (f32, f32) {
        use ab_glyph::{Font, ScaleFont};
        let font = self.font.as_scaled(size as f32);
        let mut pen = 0.0f32;
        let mut prev = None;
        for c in text.chars() {
            let id = font.glyph_id(c);
            if let Some(p) = prev {
                pen += font.kern(p, id);
            }
            prev = Some(id);
            let glyph =
                id.with_scale_and_position(size as f32, ab_glyph::point(pen, font.ascent()));
            if let Some(outline) = font.outline_glyph(glyph) {
                let b = outline.px_bounds();
                outline.draw(|x, y, c| f(b.min.x as i32 + x as i32, b.min.y as i32 + y as i32, c));
            }
            pen += font.h_advance(id);
        }
        (pen, font.ascent() - font.descent())
    }
}

impl<'a> DrawingBackend for GlyphBitmap<'a> {
    type ErrorType = <BitMapBackend<'a> as DrawingBackend>::ErrorType;

    fn get_size(&self) -> (u32, u32) {
        self.inner.get_size()
    }

    fn ensure_prepared(&mut self) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.ensure_prepared()
    }

    fn present(&mut self) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.present()
    }

    fn draw_pixel(
        &mut self,
        point: pb::BackendCoord,
        color: pb::BackendColor,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.draw_pixel(point, color)
    }

    fn draw_line<S: pb::BackendStyle>(
        &mut self,
        from: pb::BackendCoord,
        to: pb::BackendCoord,
        style: &S,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.draw_line(from, to, style)
    }

    fn draw_rect<S: pb::BackendStyle>(
        &mut self,
        upper_left: pb::BackendCoord,
        bottom_right: pb::BackendCoord,
        style: &S,
        fill: bool,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.draw_rect(upper_left, bottom_right, style, fill)
    }

    fn draw_path<S: pb::BackendStyle, I: IntoIterator<Item = pb::BackendCoord>>(
        &mut self,
        path: I,
        style: &S,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.draw_path(path, style)
    }

    fn draw_circle<S: pb::BackendStyle>(
        &mut self,
        center: pb::BackendCoord,
        radius: u32,
        style: &S,
        fill: bool,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.draw_circle(center, radius, style, fill)
    }

    fn fill_polygon<S: pb::BackendStyle, I: IntoIterator<Item = pb::BackendCoord>>(
        &mut self,
        vert: I,
        style: &S,
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.fill_polygon(vert, style)
    }

    fn blit_bitmap(
        &mut self,
        pos: pb::BackendCoord,
        size: (u32, u32),
        src: &[u8],
    ) -> std::result::Result<(), BitmapError<'a>> {
        self.inner.blit_bitmap(pos, size, src)
    }

    fn draw_text<S: pb::BackendTextStyle>(
        &mut self,
        text: &str,
        style: &S,
        pos: pb::BackendCoord,
    ) -> std::result::Result<(), BitmapError<'a>> {
        let colour = style.color();
        if colour.alpha == 0.0 {
            return Ok(());
        }
        let (w, h) = self.layout(text, style.size(), |_, _, _| {});
        let (w, h) = (w.ceil() as i32, h.ceil() as i32);
        let dx = match style.anchor().h_pos {
            HPos::Left => 0,
            HPos::Center => -w / 2,
            HPos::Right => -w,
        };
        let dy = match style.anchor().v_pos {
            VPos::Top => 0,
            VPos::Center => -h / 2,
            VPos::Bottom => -h,
        };
        let transform = style.transform();
        let (width, height) = self.get_size();
        let mut pixels = Vec::new();
        self.layout(text, style.size(), |x, y, c| {
            let (x, y) = transform.transform(x + dx, y + dy);
            let (x, y) = (pos.0 + x, pos.1 + y);
            if c > 0.0 && x >= 0 && y >= 0 && x < width as i32 && y < height as i32 {
                pixels.push(((x, y), c.min(1.0)));
            }
        });
        for (p, c) in pixels {
            let alpha = colour.alpha * c as f64;
            self.inner
                .draw_pixel(p, pb::BackendColor { alpha, ..colour })?;
        }
        Ok(())
    }

    fn estimate_text_size<S: pb::BackendTextStyle>(
        &self,
        text: &str,
        style: &S,
    ) -> std::result::Result<(u32, u32), BitmapError<'a>> {
        let (w, h) = self.layout(text, style.size(), |_, _, _| {});
        Ok((w.ceil() as u32, h.ceil() as u32))
    }
}
