//! Temporal denoising (`--temporal R`): frame t of a shot is merged with frames t−R … t+R before
//! the pipeline runs. Neighbours are reprojected by the renderer's motion pass (`motion`, read by
//! `reproject`), and each reprojected pixel counts by its agreement with frame t (`accumulate`); the
//! merged colour, its features and the variance of its mean (measured from the stack, `variance`)
//! become the render set the pipeline sees, so every stage's strength follows the lower noise.
//! `window` holds the frames loaded.

pub mod accumulate;
pub mod motion;
pub mod reproject;
pub mod variance;
pub mod window;

use crate::error::{Error, Result};
use crate::io::LoadedSet;
use accumulate::merge;
use motion::{track, Slot};
use window::{Held, Window};

/// Most frames on each side (the pipeline key's bound too).
pub use crate::spec::MAX_TEMPORAL_RADIUS as MAX_RADIUS;

/// A shot denoised frame by frame with its neighbours.
pub struct Shot {
    window: Window,
    /// A neighbour that cannot be read fails the frame instead of being left out.
    pub strict: bool,
    told_static: bool,
}

impl Shot {
    /// A shot merged over `radius` frames each side; errors (exit 2) beyond [`MAX_RADIUS`].
    pub fn new(radius: usize, strict: bool) -> Result<Self> {
        if radius > MAX_RADIUS {
            return Err(Error::range(
                "--temporal",
                radius,
                &format!("0 to {MAX_RADIUS} frames each side"),
            ));
        }
        Ok(Shot {
            window: Window::new(radius),
            strict,
            told_static: false,
        })
    }

    /// Frame `t` merged with its neighbours, as the render set the pipeline denoises: the centre's
    /// files, frame and notes, with the merged buffers and a note on what was merged. `load` reads
    /// a frame of the shot (`None`: outside the shot).
    pub fn frame(
        &mut self,
        t: u64,
        load: &dyn Fn(u64) -> Option<Result<LoadedSet>>,
    ) -> Result<LoadedSet> {
        self.window.slide(t, load)?;
        let mut notes = Vec::new();
        let mut numbers = Vec::new();
        let mut outside = Vec::new();
        let mut sets = Vec::new();
        let mut slots = Vec::new();
        for (n, held) in self.window.frames(t) {
            let set = match held {
                Held::Loaded(set) => Some(set.as_ref()),
                Held::Outside => None,
                Held::Failed(why) if self.strict => {
                    return Err(Error::config(
                        "--temporal-strict",
                        format!("neighbour frame {n} cannot be used: {why}"),
                    ))
                }
                Held::Failed(why) => {
                    notes.push(format!(
                        "neighbour frame {n} left out (merged from fewer frames): {why}"
                    ));
                    None
                }
            };
            numbers.push(n);
            outside.push(matches!(held, Held::Outside));
            slots.push(Slot {
                present: set.is_some(),
                motion: set.and_then(|s| s.motion.as_ref()),
            });
            sets.push(set);
        }
        let centre = numbers.iter().position(|&n| n == t).expect("the centre");
        let own = sets[centre].expect("the centre is loaded");
        let dims = own.set.dims();
        // A neighbour of another size cannot be merged: it is left out like an unreadable one.
        for (k, set) in sets.iter_mut().enumerate() {
            if set.is_some_and(|s| s.set.dims() != dims) {
                let msg = format!(
                    "neighbour frame {} is {}x{}, not {}x{}",
                    numbers[k],
                    set.map_or(0, |s| s.set.dims().0),
                    set.map_or(0, |s| s.set.dims().1),
                    dims.0,
                    dims.1
                );
                if self.strict {
                    return Err(Error::config("--temporal-strict", msg));
                }
                notes.push(format!("{msg}: left out"));
                *set = None;
                slots[k].present = false;
            }
        }
        if !slots.iter().any(|s| s.motion.is_some()) && !self.told_static {
            self.told_static = true;
            notes.push(
                "no motion pass (Blender Vector, motionBack/motionFore, motionvector): the shot is assumed static"
                    .to_string(),
            );
        }
        let tracks = track(&slots, centre, dims);
        let renders: Vec<_> = sets.iter().map(|s| s.map(|s| &s.set)).collect();
        let merged = merge(&renders, &tracks, centre);
        let shares: Vec<String> = numbers
            .iter()
            .zip(&merged.weights)
            .zip(&outside)
            .filter(|((&n, _), &out)| n != t && !out)
            .map(|((n, w), _)| format!("{n} {:.0} %", 100.0 * w))
            .collect();
        notes.push(format!(
            "temporal: merged with frames (mean weight) {}",
            if shares.is_empty() {
                "none".to_string()
            } else {
                shares.join(", ")
            }
        ));
        let mut all_notes = own.notes.clone();
        all_notes.extend(notes);
        Ok(LoadedSet {
            dir: own.dir.clone(),
            set: merged.set,
            files: own.files.clone(),
            sources: own.sources.clone(),
            reference: own.reference.clone(),
            notes: all_notes,
            layered: own.layered,
            frame: own.frame.clone(),
            motion: None,
        })
    }
}
