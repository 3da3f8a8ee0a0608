//! Frame patterns (`beauty.####.exr`, `%04d`, `$F4`) and `--frames` lists: which frames a
//! sequence run names, and the path of each.

use std::path::Path;

use crate::error::{Error, Result};

/// Most frames one `--frames` list may name: far beyond a shot, so a larger count is a typo.
const MAX_FRAMES: u64 = 1_000_000;

/// A path with one frame token: `#` runs (`####` = 4 digits), printf's `%04d` or Houdini's `$F4`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Pattern {
    /// The path as written, for messages.
    text: String,
    prefix: String,
    suffix: String,
    /// Fewest digits a frame number is written with (zero-padded).
    width: usize,
}

impl Pattern {
    /// The frame token of `text`, if it has one; two tokens are an error.
    pub fn find(text: &str) -> Result<Option<Pattern>> {
        let bytes = text.as_bytes();
        let mut found: Option<(usize, usize, usize)> = None;
        let mut i = 0;
        while i < bytes.len() {
            let Some((len, width)) = token_at(&bytes[i..]) else {
                i += 1;
                continue;
            };
            if found.is_some() {
                return Err(Error::config(
                    text,
                    "has two frame tokens; a path takes one (####, %04d or $F4)",
                ));
            }
            found = Some((i, i + len, width));
            i += len;
        }
        Ok(found.map(|(start, end, width)| Pattern {
            text: text.to_string(),
            prefix: text[..start].to_string(),
            suffix: text[end..].to_string(),
            width,
        }))
    }

    /// The path as written.
    pub fn text(&self) -> &str {
        &self.text
    }

    /// The pattern with frame `n` written in.
    pub fn frame(&self, n: u64) -> String {
        format!(
            "{}{n:0width$}{}",
            self.prefix,
            self.suffix,
            width = self.width
        )
    }

    /// The frames whose files exist, in order. The token must be in the file name (not a folder),
    /// and a `:Layer` after the file name is not part of it.
    pub fn existing_frames(&self) -> Result<Vec<u64>> {
        let shown = &self.text;
        let (dir, head) = match self.prefix.rfind('/') {
            Some(i) => (&self.prefix[..=i], &self.prefix[i + 1..]),
            None => ("", self.prefix.as_str()),
        };
        if self.suffix.contains('/') {
            return Err(Error::config(
                shown,
                "has its frame token in a folder name; give the frames with --frames",
            ));
        }
        let tail = self.suffix.split(':').next().unwrap_or("");
        let folder = if dir.is_empty() {
            Path::new(".")
        } else {
            Path::new(dir)
        };
        let entries = std::fs::read_dir(folder)
            .map_err(|e| Error::file(folder, format!("cannot list the frames of {shown}: {e}")))?;
        let mut frames: Vec<u64> = entries
            .filter_map(|e| e.ok()?.file_name().into_string().ok())
            .filter_map(|name| {
                let digits = name.strip_prefix(head)?.strip_suffix(tail)?;
                let n: u64 = digits
                    .bytes()
                    .all(|b| b.is_ascii_digit())
                    .then(|| digits.parse().ok())??;
                // Only the file this pattern writes for `n` (`0012` for `####`, not `012`).
                (format!("{n:0width$}", width = self.width) == digits).then_some(n)
            })
            .collect();
        frames.sort_unstable();
        if frames.is_empty() {
            return Err(Error::file(shown, "no frames found (no file matches)"));
        }
        Ok(frames)
    }
}

/// The frame token starting `s`, as (its length, the frame number's width).
fn token_at(s: &[u8]) -> Option<(usize, usize)> {
    let digits = |s: &[u8]| s.iter().take_while(|b| b.is_ascii_digit()).count();
    let number = |s: &[u8]| std::str::from_utf8(s).ok()?.parse::<usize>().ok();
    match s {
        [b'#', ..] => {
            let n = s.iter().take_while(|&&b| b == b'#').count();
            Some((n, n))
        }
        [b'%', b'd', ..] => Some((2, 1)),
        [b'%', b'0', rest @ ..] => {
            let n = digits(rest);
            (n > 0 && rest.get(n) == Some(&b'd')).then(|| (n + 3, number(&rest[..n]).unwrap_or(1)))
        }
        [b'$', b'F', rest @ ..] => {
            let n = digits(rest);
            if n > 0 {
                Some((n + 2, number(&rest[..n]).unwrap_or(1)))
            } else if rest
                .first()
                .is_some_and(|b| b.is_ascii_alphabetic() || *b == b'_')
            {
                None // another variable (`$FPS`, `$F_x`), not the frame
            } else {
                Some((2, 1))
            }
        }
        _ => None,
    }
}

/// Parses a `--frames` list: `A-B`, `A-BxSTEP`, single frames, comma-separated; sorted, each once.
pub fn parse_frames(text: &str) -> Result<Vec<u64>> {
    let bad = |part: &str, why: &str| Error::config("--frames", format!("`{part}` {why}"));
    let number = |part: &str, s: &str| {
        s.trim()
            .parse::<u64>()
            .map_err(|_| bad(part, "is not A, A-B or A-BxSTEP (whole frame numbers ≥ 0)"))
    };
    let mut frames = Vec::new();
    for part in text.split(',') {
        let (range, step) = match part.split_once('x') {
            Some((r, s)) => (r, number(part, s)?),
            None => (part, 1),
        };
        let (a, b) = match range.split_once('-') {
            Some((a, b)) => (number(part, a)?, number(part, b)?),
            None if part.contains('x') => return Err(bad(part, "has a step but no range")),
            None => {
                let a = number(part, range)?;
                (a, a)
            }
        };
        if a > b {
            return Err(bad(part, "ends before it starts"));
        }
        if step == 0 {
            return Err(bad(part, "has step 0"));
        }
        if (b - a) / step + 1 + frames.len() as u64 > MAX_FRAMES {
            return Err(bad(part, &format!("makes more than {MAX_FRAMES} frames")));
        }
        frames.extend((a..=b).step_by(step as usize));
    }
    frames.sort_unstable();
    frames.dedup();
    Ok(frames)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pattern(text: &str) -> Pattern {
        Pattern::find(text).unwrap().expect("a frame token")
    }

    #[test]
    fn frame_tokens_of_every_style_write_the_same_zero_padded_numbers() {
        for text in ["shot/b.####.exr", "shot/b.%04d.exr", "shot/b.$F4.exr"] {
            let p = pattern(text);
            assert_eq!(p.frame(7), "shot/b.0007.exr", "{text}");
            assert_eq!(p.frame(12345), "shot/b.12345.exr", "{text}");
        }
        for text in ["b.#.exr", "b.%d.exr", "b.$F.exr"] {
            assert_eq!(pattern(text).frame(7), "b.7.exr", "{text}");
        }
        assert_eq!(pattern("a_##_x").frame(3), "a_03_x");
        for plain in [
            "shot/b.0001.exr",
            "b.exr",
            "$FPS.exr",
            "100%.exr",
            "%5d.exr",
        ] {
            assert_eq!(Pattern::find(plain).unwrap(), None, "{plain}");
        }
        assert!(Pattern::find("s.####/b.####.exr").is_err());
        assert!(Pattern::find("b.%04d.$F4.exr").is_err());
    }

    #[test]
    fn frames_lists_take_ranges_steps_and_commas() {
        assert_eq!(parse_frames("1001-1004").unwrap(), [1001, 1002, 1003, 1004]);
        assert_eq!(parse_frames("1-10x3").unwrap(), [1, 4, 7, 10]);
        assert_eq!(parse_frames("5,1,3-4").unwrap(), [1, 3, 4, 5]);
        assert_eq!(parse_frames("7").unwrap(), [7]);
        assert_eq!(
            parse_frames("1-3,2-4").unwrap(),
            [1, 2, 3, 4],
            "each frame once"
        );
        assert_eq!(parse_frames("0-0").unwrap(), [0]);
        assert_eq!(parse_frames(" 2 - 4 ").unwrap(), [2, 3, 4]);
        for bad in [
            "",
            "a",
            "5-1",
            "1-5x0",
            "1-",
            "-3",
            "1,,2",
            "1-5x",
            "3x2",
            "1.5",
            "0-1000000",
        ] {
            let err = parse_frames(bad)
                .err()
                .unwrap_or_else(|| panic!("`{bad}` was accepted"));
            assert_eq!(err.exit_code(), 2);
            assert!(err.to_string().starts_with("--frames: "), "{err}");
        }
    }

    #[test]
    fn existing_frames_are_the_files_the_pattern_writes_sorted() {
        let tmp = tempfile::tempdir().unwrap();
        for name in [
            "b.0010.exr",
            "b.0002.exr",
            "b.0001.exr",
            "b.001.exr",
            "b.12345.exr",
            "b.00x1.exr",
            "c.0003.exr",
            "b.0004.exr.tmp",
        ] {
            std::fs::write(tmp.path().join(name), b"").unwrap();
        }
        let dir = tmp.path().to_str().unwrap();
        let p = pattern(&format!("{dir}/b.####.exr"));
        assert_eq!(p.existing_frames().unwrap(), [1, 2, 10, 12345]);
        let layered = pattern(&format!("{dir}/b.####.exr:ViewLayer.Combined"));
        assert_eq!(layered.existing_frames().unwrap(), [1, 2, 10, 12345]);
        let none = pattern(&format!("{dir}/d.####.exr"));
        assert_eq!(none.existing_frames().err().unwrap().exit_code(), 2);
    }
}
