//! Hints for habits other tools teach that clap would answer with a confusing message.

use std::ffi::OsString;
use std::path::Path;

/// Open Image Denoise's `oidnDenoise -q`/`--quality` values.
const OIDN_QUALITY: [&str; 4] = ["high", "balanced", "fast", "default"];

/// The hint for `-q VALUE` (oidnDenoise's quality, `-q high`), gsid's `-q` being `--quiet`: for a
/// value oidnDenoise knows, always; for any other word after `-q`, only when clap refused the
/// line (`parse_failed`) and the word is not a path that exists.
pub(super) fn quality_flag(args: &[OsString], parse_failed: bool) -> Option<String> {
    let value = args
        .windows(2)
        .find(|w| w[0] == "-q" || w[0] == "--quiet")
        .map(|w| &w[1])?;
    let text = value.to_str()?;
    let known = OIDN_QUALITY.iter().any(|q| q.eq_ignore_ascii_case(text));
    let command = [
        "denoise",
        "eval",
        "pipelines",
        "render",
        "ablate",
        "sweep",
        "help",
    ];
    let stray = parse_failed
        && !text.starts_with('-')
        && !command.contains(&text)
        && !Path::new(text).exists();
    (known && !Path::new(text).exists() || stray).then(|| {
        format!(
            "-q is --quiet and takes no value (`-q {text}` is oidnDenoise's quality): choose the quality with -p fast|balanced|quality|full"
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(line: &str) -> Vec<OsString> {
        line.split(' ').map(OsString::from).collect()
    }

    #[test]
    fn a_quality_after_q_gets_the_preset_hint() {
        let hint = quality_flag(&args("gsid denoise -q high --hdr c.pfm -o o.pfm"), false);
        assert!(hint.unwrap().contains("-p fast|balanced|quality|full"));
        assert!(quality_flag(&args("gsid denoise -q ultra x -o o.exr"), true).is_some());
        assert_eq!(
            quality_flag(&args("gsid denoise -q ultra -o o.exr"), false),
            None
        );
        assert_eq!(
            quality_flag(&args("gsid denoise -q -o o.exr x"), true),
            None
        );
        assert_eq!(
            quality_flag(&args("gsid denoise -q src -o o.exr"), true),
            None
        );
    }
}
