//! Animations: `submit 'shot/scene.####.toml' --frames 1-250` (or several scene files)
//! submits one job per frame, named `NAME.0001`, … as one group. Files the frames share
//! (unchanged meshes, materials, textures) are uploaded once for the group; `--wait`
//! follows the frames in order and writes each image to the output pattern
//! (`-o shot.####.exr`; without `#`, the frame number goes before the extension).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use proto::domain::AssetRef;

use crate::edge::client::FarmClient;
use crate::farm::assets::LocalScene;

/// Most frames one submission may name (a typo like `1-1000000` is refused, not queued).
pub const MAX_FRAMES: u32 = 100_000;

/// `--frames`: an inclusive range `A-B` (or one frame `A`).
pub fn frame_range(s: &str) -> Result<(u32, u32), String> {
    let (a, b) = s.split_once('-').unwrap_or((s, s));
    let num = |t: &str| t.trim().parse::<u32>().map_err(|_| format!("{s:?} is not a frame range such as 1-250"));
    let (a, b) = (num(a)?, num(b)?);
    if b < a {
        return Err(format!("{s}: the last frame comes before the first"));
    }
    if b - a >= MAX_FRAMES {
        return Err(format!("{s}: more than {MAX_FRAMES} frames"));
    }
    Ok((a, b))
}

/// `pattern` with its run of `#` replaced by `frame`, zero-padded to the run's length;
/// `None` if it has no `#`.
pub fn with_frame(pattern: &str, frame: u32) -> Option<String> {
    let start = pattern.find('#')?;
    let len = pattern[start..].chars().take_while(|&c| c == '#').count();
    Some(format!("{}{frame:0len$}{}", &pattern[..start], &pattern[start + len..]))
}

/// Where frame `frame`'s image goes: `output` with its `#` run replaced, or with
/// `.####` before its extension.
pub fn frame_output(output: &Path, frame: u32) -> PathBuf {
    let text = output.to_string_lossy();
    if let Some(p) = with_frame(&text, frame) {
        return PathBuf::from(p);
    }
    let stem = output.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let ext = output.extension().map(|e| format!(".{}", e.to_string_lossy())).unwrap_or_default();
    output.with_file_name(format!("{stem}.{frame:04}{ext}"))
}

/// The frames to submit: (frame number, scene file). `--frames` over one pattern, or
/// the scene files given, numbered from 1 in order.
pub fn frame_scenes(scenes: &[PathBuf], frames: Option<(u32, u32)>) -> anyhow::Result<Vec<(u32, PathBuf)>> {
    match frames {
        Some((a, b)) => {
            let [pattern] = scenes else { bail!("--frames takes one scene pattern (such as shot/scene.####.toml)") };
            let text = pattern.to_string_lossy();
            if !text.contains('#') {
                bail!("--frames: {} has no #### for the frame number", pattern.display());
            }
            Ok((a..=b).map(|f| (f, PathBuf::from(with_frame(&text, f).expect("has #")))).collect())
        }
        None => Ok(scenes.iter().enumerate().map(|(i, p)| (i as u32 + 1, p.clone())).collect()),
    }
}

/// A group's name: `--name`, else the pattern's (or first scene's) file name with its
/// frame number and extension taken off (`shot/scene.####.toml` → `scene`).
pub fn group_name(first: &Path) -> String {
    let name = first.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let base = name.split('.').next().unwrap_or("").to_string();
    if base.is_empty() { "frames".into() } else { base }
}

/// Uploads, once each for the whole group, the files of every frame.
#[derive(Default)]
pub struct GroupUpload {
    by_digest: HashMap<(String, String), AssetRef>,
    /// Bytes sent, and bytes that one submission per frame would have sent.
    pub sent: u64,
    pub per_frame: u64,
    pub files_sent: usize,
}

impl GroupUpload {
    /// The frame's scene and files as uploaded assets (sending only what the group has
    /// not sent yet).
    pub async fn frame(&mut self, client: &mut FarmClient, scene: &Path) -> anyhow::Result<(AssetRef, Vec<AssetRef>)> {
        let local = LocalScene::collect(scene)?;
        if !local.missing.is_empty() {
            let list: Vec<String> = local.missing.iter().map(|m| format!("  {}", local.relative(m))).collect();
            bail!(
                "{} refers to files that are missing, so nothing was submitted:\n{}",
                scene.display(),
                list.join("\n")
            );
        }
        let scene_ref = self.file(client, &local.scene, local.relative(&local.scene)).await?;
        let mut assets = Vec::with_capacity(local.files.len());
        for f in &local.files {
            assets.push(self.file(client, f, local.relative(f)).await?);
        }
        Ok((scene_ref, assets))
    }

    async fn file(&mut self, client: &mut FarmClient, path: &Path, rel: String) -> anyhow::Result<AssetRef> {
        let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let digest = crate::farm::assets::sha256_hex(&bytes);
        self.per_frame += bytes.len() as u64;
        if let Some(a) = self.by_digest.get(&(rel.clone(), digest.clone())) {
            return Ok(a.clone());
        }
        let a = client.upload(path, rel.clone()).await?;
        self.sent += a.size;
        self.files_sent += 1;
        self.by_digest.insert((rel, digest), a.clone());
        Ok(a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_patterns_and_outputs() {
        assert_eq!(frame_range("1-250"), Ok((1, 250)));
        assert_eq!(frame_range("7"), Ok((7, 7)));
        assert!(frame_range("9-3").unwrap_err().contains("before the first"));
        assert!(frame_range("1-x").is_err());
        assert!(frame_range("0-100000").unwrap_err().contains("more than"));
        assert_eq!(with_frame("shot/scene.####.toml", 7).as_deref(), Some("shot/scene.0007.toml"));
        assert_eq!(with_frame("a.##.exr", 123).as_deref(), Some("a.123.exr"), "wider numbers are not cut");
        assert_eq!(with_frame("plain.toml", 1), None);
        assert_eq!(frame_output(Path::new("out/shot.####.exr"), 12), PathBuf::from("out/shot.0012.exr"));
        assert_eq!(frame_output(Path::new("out/shot.exr"), 12), PathBuf::from("out/shot.0012.exr"));
        assert_eq!(group_name(Path::new("shot/scene.####.toml")), "scene");
        let scenes = frame_scenes(&[PathBuf::from("s.####.toml")], Some((2, 4))).unwrap();
        assert_eq!(scenes.iter().map(|(f, _)| *f).collect::<Vec<_>>(), [2, 3, 4]);
        assert_eq!(scenes[0].1, PathBuf::from("s.0002.toml"));
        assert!(frame_scenes(&[PathBuf::from("s.toml")], Some((1, 2))).is_err());
        let listed = frame_scenes(&[PathBuf::from("a.toml"), PathBuf::from("b.toml")], None).unwrap();
        assert_eq!(listed, [(1, PathBuf::from("a.toml")), (2, PathBuf::from("b.toml"))]);
    }
}
