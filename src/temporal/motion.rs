//! Where each pixel of the centre frame lies in every frame of the window: the renderer's motion
//! offsets chained frame by frame (t → t±1 → t±2 …), so a neighbour two frames away is found through
//! the frame between. Without any motion pass the shot is taken as static (every pixel stays put).

use super::reproject::nearest;
use crate::image::Image;
use crate::io::passes::MotionPass;

/// A position that lies in no frame (the chain left the image or broke).
pub const NOWHERE: [f32; 2] = [f32::NAN, f32::NAN];

/// One frame of the window as the tracker sees it: present or not, and its motion pass.
#[derive(Clone, Copy)]
pub struct Slot<'a> {
    pub present: bool,
    pub motion: Option<&'a MotionPass>,
}

/// Positions (x, y in pixels, y down) of every centre pixel in each window frame, `None` for a
/// frame that cannot be reached (missing, or a frame between has no motion that way).
pub fn track(slots: &[Slot], centre: usize, (w, h): (usize, usize)) -> Vec<Option<Vec<[f32; 2]>>> {
    let identity: Vec<[f32; 2]> = (0..w * h)
        .map(|i| [(i % w) as f32, (i / w) as f32])
        .collect();
    let moving = slots.iter().any(|s| s.present && s.motion.is_some());
    let mut out: Vec<Option<Vec<[f32; 2]>>> = vec![None; slots.len()];
    for (j, slot) in slots.iter().enumerate() {
        if slot.present && (j == centre || !moving) {
            out[j] = Some(identity.clone());
        }
    }
    if !moving {
        return out;
    }
    // Outwards from the centre, each step by the motion of the frame it starts from.
    for dir in [-1i64, 1] {
        let mut j = centre as i64;
        loop {
            let next = j + dir;
            if next < 0 || next as usize >= slots.len() {
                break;
            }
            let (from, to) = (j as usize, next as usize);
            let offsets = slots[from].motion.and_then(|m| {
                if dir < 0 {
                    m.back.as_ref()
                } else {
                    m.fore.as_ref()
                }
            });
            let (Some(offsets), true, Some(here)) = (offsets, slots[to].present, &out[from]) else {
                break;
            };
            out[to] = Some(step(here, offsets));
            j = next;
        }
    }
    out
}

/// Moves every position by the offset of the pixel it falls on (nearest: an offset averaged
/// across an object's edge would point between the two motions).
fn step(positions: &[[f32; 2]], offsets: &Image) -> Vec<[f32; 2]> {
    positions
        .iter()
        .map(|&[x, y]| {
            let Some((xi, yi)) = nearest(offsets, [x, y]) else {
                return NOWHERE;
            };
            let o = offsets.at(xi, yi);
            let moved = [x + o[0], y + o[1]];
            if moved.iter().all(|v| v.is_finite()) {
                moved
            } else {
                NOWHERE
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pass(w: usize, h: usize, back: [f32; 2], fore: [f32; 2]) -> MotionPass {
        let field = |o: [f32; 2]| Image::from_fn(w, h, 2, |_, _, c| o[c]);
        MotionPass {
            back: Some(field(back)),
            fore: Some(field(fore)),
            source: String::new(),
        }
    }

    #[test]
    fn offsets_chain_outwards_and_a_gap_stops_the_chain() {
        let m = pass(8, 8, [-1.0, 0.0], [1.0, 0.5]);
        let slot = |present| Slot {
            present,
            motion: Some(&m),
        };
        let t = track(&[slot(true), slot(true), slot(true), slot(true)], 1, (8, 8));
        assert_eq!(t[1].as_ref().unwrap()[9], [1.0, 1.0]);
        assert_eq!(t[0].as_ref().unwrap()[9], [0.0, 1.0]);
        assert_eq!(t[2].as_ref().unwrap()[9], [2.0, 1.5]);
        assert_eq!(t[3].as_ref().unwrap()[9], [3.0, 2.0]);
        let gap = track(
            &[slot(true), slot(true), slot(false), slot(true)],
            1,
            (8, 8),
        );
        assert!(gap[2].is_none() && gap[3].is_none() && gap[0].is_some());
    }

    #[test]
    fn without_motion_every_present_frame_is_taken_as_it_is() {
        let slot = |present| Slot {
            present,
            motion: None,
        };
        let t = track(&[slot(true), slot(false), slot(true)], 1, (4, 4));
        assert_eq!(t[0].as_ref().unwrap()[5], [1.0, 1.0]);
        assert!(t[1].is_none());
        assert!(t[2].is_some());
    }
}
