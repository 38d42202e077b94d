//! What lies beside a stored image (`<images>/<job>.exr`), so that a job no longer listed
//! (forgotten after `retain`, or from before a restart) can still be fetched by whoever
//! may: `<job>.owner` names the user who owns it, and `<job>.frame` the job group and
//! frame name of a group's frame, so that `fetch NAME` finds a group's finished frames.
//! Both are read back bounded, since the folder may hold anything.

use std::path::Path;

use anyhow::Context;

/// Beside a stored image, `<job>.owner` names the user who may fetch it (none: admins).
pub const OWNER_SUFFIX: &str = "owner";
/// Beside a stored frame's image, `<job>.frame`: its group's name, a newline, its name.
pub const FRAME_SUFFIX: &str = "frame";
/// Longest sidecar read back, in bytes (names are bounded far below this on submission).
const MAX_SIDECAR: u64 = 4096;

pub fn write_owner(images: &Path, job: &str, owner: Option<&str>) -> anyhow::Result<()> {
    let Some(owner) = owner else { return Ok(()) };
    let path = images.join(format!("{job}.{OWNER_SUFFIX}"));
    std::fs::write(&path, owner).with_context(|| format!("writing {}", path.display()))
}

/// Who owns the stored image of a job no longer listed (None: an admin's).
pub fn stored_owner(image: &Path) -> Option<String> {
    let text = read_bounded(&image.with_extension(OWNER_SUFFIX))?;
    Some(text.chars().take(64).collect())
}

/// Records that `job` is the frame `name` of group `group` (nothing for other jobs).
pub fn write_frame(images: &Path, job: &str, group: Option<&str>, name: &str) -> anyhow::Result<()> {
    let Some(group) = group else { return Ok(()) };
    let path = images.join(format!("{job}.{FRAME_SUFFIX}"));
    std::fs::write(&path, format!("{group}\n{name}")).with_context(|| format!("writing {}", path.display()))
}

/// The frame name recorded beside a stored image, if it was a group's frame.
pub fn stored_frame_name(image: &Path) -> Option<String> {
    let text = read_bounded(&image.with_extension(FRAME_SUFFIX))?;
    text.split_once('\n').map(|(_, name)| name.to_string())
}

/// A group's frame whose image is stored.
#[derive(Debug, PartialEq, Eq)]
pub struct StoredFrame {
    pub job: String,
    pub name: String,
    pub owner: Option<String>,
}

/// The stored frames of group `group` in `images` (whose `.exr` is there), by name.
pub fn stored_frames(images: &Path, group: &str) -> Vec<StoredFrame> {
    let entries = std::fs::read_dir(images).into_iter().flatten().flatten();
    let mut frames: Vec<StoredFrame> = entries
        .filter_map(|e| {
            let file = e.file_name();
            let job = file.to_str()?.strip_suffix(FRAME_SUFFIX)?.strip_suffix('.')?;
            let number = job.strip_prefix("job-")?;
            if number.is_empty() || !number.bytes().all(|b| b.is_ascii_digit()) {
                return None;
            }
            let text = read_bounded(&e.path())?;
            let (g, name) = text.split_once('\n')?;
            let image = images.join(format!("{job}.exr"));
            (g == group && image.is_file()).then(|| StoredFrame {
                job: job.to_string(),
                name: name.to_string(),
                owner: stored_owner(&image),
            })
        })
        .collect();
    frames.sort_by(|a, b| a.name.cmp(&b.name).then_with(|| a.job.cmp(&b.job)));
    frames
}

/// A sidecar's text, or None if it is missing, not a regular file, not UTF-8 or longer
/// than [`MAX_SIDECAR`].
fn read_bounded(path: &Path) -> Option<String> {
    String::from_utf8(tracer::scene::files::read_bounded(path, MAX_SIDECAR).ok()?).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A group's frames come back by name with their owners; other groups' frames,
    /// frames whose image is gone, odd file names and oversized sidecars do not.
    #[test]
    fn a_groups_stored_frames_are_found_and_nothing_else() {
        let dir = std::env::temp_dir().join(format!("tilefarm-stored-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let image = |job: &str| std::fs::write(dir.join(format!("{job}.exr")), b"exr").unwrap();
        for (job, group, name, owner) in [
            ("job-7", "walk", "walk.0002", Some("ann")),
            ("job-3", "walk", "walk.0001", None),
            ("job-9", "pan", "pan.0001", Some("bob")),
            ("job-11", "walk", "walk.0003", Some("ann")),
        ] {
            image(job);
            write_owner(&dir, job, owner).unwrap();
            write_frame(&dir, job, Some(group), name).unwrap();
        }
        // Not frames: a plain job, a frame whose image is gone, names that are no job's.
        image("job-12");
        write_frame(&dir, "job-12", None, "still").unwrap();
        write_frame(&dir, "job-13", Some("walk"), "walk.0004").unwrap();
        std::fs::write(dir.join("x.frame"), "walk\nwalk.0005").unwrap();
        std::fs::write(dir.join("job-.frame"), "walk\nwalk.0006").unwrap();
        image("job-14");
        std::fs::write(dir.join("job-14.frame"), format!("walk\n{}", "x".repeat(5000))).unwrap();

        let walk = stored_frames(&dir, "walk");
        let got: Vec<(&str, &str, Option<&str>)> =
            walk.iter().map(|f| (f.job.as_str(), f.name.as_str(), f.owner.as_deref())).collect();
        assert_eq!(
            got,
            [("job-3", "walk.0001", None), ("job-7", "walk.0002", Some("ann")), ("job-11", "walk.0003", Some("ann"))]
        );
        assert_eq!(stored_frames(&dir, "pan").len(), 1);
        assert!(stored_frames(&dir, "still").is_empty() && stored_frames(&dir, "wal").is_empty());
        assert!(!dir.join("job-12.frame").exists(), "a job of no group gets no frame file");
        std::fs::remove_dir_all(&dir).ok();
    }
}
