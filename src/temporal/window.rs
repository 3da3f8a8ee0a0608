//! The sliding window of a shot: frames t−R … t+R as loaded, each read once while the window passes
//! over it and dropped when it leaves, so memory is bounded by 2R+1 frames, never the shot's length.

use std::collections::BTreeMap;

use crate::error::{Error, Result};
use crate::io::LoadedSet;

/// One frame of the window.
pub enum Held {
    Loaded(Box<LoadedSet>),
    /// Outside the shot (before its first or after its last frame): absent without a note.
    Outside,
    /// Could not be read: the one-line reason, naming the file.
    Failed(String),
}

/// Frames held by number.
pub struct Window {
    radius: u64,
    held: BTreeMap<u64, Held>,
}

impl Window {
    pub fn new(radius: usize) -> Self {
        Window {
            radius: radius as u64,
            held: BTreeMap::new(),
        }
    }

    /// Moves the window to centre `t`: drops the frames outside it and loads the new ones with
    /// `load` (`None`: outside the shot). A centre that cannot be read is its frame's error.
    pub fn slide(&mut self, t: u64, load: &dyn Fn(u64) -> Option<Result<LoadedSet>>) -> Result<()> {
        let (first, last) = (t.saturating_sub(self.radius), t.saturating_add(self.radius));
        self.held.retain(|&n, _| (first..=last).contains(&n));
        // A centre that failed as a neighbour is read again, for its own error.
        if matches!(self.held.get(&t), Some(Held::Failed(_))) {
            self.held.remove(&t);
        }
        for n in first..=last {
            if self.held.contains_key(&n) {
                continue;
            }
            let held = match load(n) {
                None => Held::Outside,
                Some(Ok(set)) => Held::Loaded(Box::new(set)),
                Some(Err(e)) if n == t => return Err(e),
                Some(Err(e)) => Held::Failed(e.to_string()),
            };
            self.held.insert(n, held);
        }
        match self.held.get(&t) {
            Some(Held::Loaded(_)) => Ok(()),
            _ => Err(Error::config(
                "--frames",
                format!("frame {t} is outside the shot's files"),
            )),
        }
    }

    /// The window's frames in order, from t−R (fewer near frame 0).
    pub fn frames(&self, t: u64) -> impl Iterator<Item = (u64, &Held)> {
        let first = t.saturating_sub(self.radius);
        self.held
            .range(first..=t.saturating_add(self.radius))
            .map(|(&n, h)| (n, h))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::image::Image;
    use crate::render_set::RenderSet;

    #[test]
    fn a_long_shot_holds_at_most_2r_plus_1_frames_and_reads_each_once() {
        let reads = std::cell::RefCell::new(Vec::new());
        let load = |n: u64| -> Option<Result<LoadedSet>> {
            reads.borrow_mut().push(n);
            (1..=40).contains(&n).then(|| {
                Ok(LoadedSet {
                    dir: Default::default(),
                    set: RenderSet::new(Image::filled(2, 2, 3, n as f32)),
                    files: Vec::new(),
                    sources: Vec::new(),
                    reference: None,
                    notes: Vec::new(),
                    layered: false,
                    frame: Default::default(),
                    motion: None,
                })
            })
        };
        let mut window = Window::new(2);
        for t in 1..=40 {
            window.slide(t, &load).unwrap();
            assert!(
                window.held.len() <= 5,
                "frame {t}: {} held",
                window.held.len()
            );
            let numbers: Vec<u64> = window.frames(t).map(|(n, _)| n).collect();
            assert_eq!(numbers.first(), Some(&t.saturating_sub(2)));
        }
        // Every frame of 0..=42 (0, 41 and 42 lie outside the shot) asked for once.
        assert_eq!(*reads.borrow(), (0..=42).collect::<Vec<_>>());
    }
}
