//! The one way the scene loaders read a file: only regular files (a device, FIFO or
//! socket named by a scene would block or never end: `mtllib /dev/zero` read until
//! memory ran out), and only up to a size for each kind, so a hostile or broken scene
//! gets a clear error instead of exhausting memory.

use std::io::Read;
use std::path::Path;

/// Largest scene file (TOML).
pub const MAX_SCENE_BYTES: u64 = 16 << 20;
/// Largest OBJ file.
pub const MAX_OBJ_BYTES: u64 = 4 << 30;
/// Largest MTL file.
pub const MAX_MTL_BYTES: u64 = 64 << 20;
/// Largest texture file, and the most its decoding may allocate.
pub const MAX_TEXTURE_BYTES: u64 = 1 << 30;
/// Largest environment map file, and the most its decoding may allocate (a 16k × 8k
/// RGBA float image is 2 GiB).
pub const MAX_ENVIRONMENT_BYTES: u64 = 3 << 30;
/// Widest and tallest environment map, in texels.
pub const MAX_ENVIRONMENT_SIZE: (u32, u32) = (16_384, 8_192);

/// Checks that `path` is a regular file of at most `limit` bytes (following symlinks).
pub fn check_regular(path: &Path, limit: u64) -> std::io::Result<u64> {
    let meta = std::fs::metadata(path)?;
    if !meta.file_type().is_file() {
        return Err(std::io::Error::other("not a regular file (a device, pipe, socket or folder)"));
    }
    if meta.len() > limit {
        return Err(std::io::Error::other(format!("{} bytes, more than the {} allowed", meta.len(), limit)));
    }
    Ok(meta.len())
}

/// Reads a regular file of at most `limit` bytes (a file that grows while being read
/// is cut off at the limit and refused).
pub fn read_bounded(path: &Path, limit: u64) -> std::io::Result<Vec<u8>> {
    let len = check_regular(path, limit)?;
    let mut bytes = Vec::with_capacity(len as usize);
    std::fs::File::open(path)?.take(limit + 1).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > limit {
        return Err(std::io::Error::other(format!("more than the {limit} bytes allowed")));
    }
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_regular_files_within_their_limit_are_read() {
        let dir = std::env::temp_dir().join(format!("tilefarm-files-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("a.txt");
        std::fs::write(&f, b"12345").unwrap();
        assert_eq!(read_bounded(&f, 5).unwrap(), b"12345");
        assert!(read_bounded(&f, 4).unwrap_err().to_string().contains("more than the 4"));
        assert!(read_bounded(&dir, 100).unwrap_err().to_string().contains("not a regular file"));
        #[cfg(unix)]
        {
            let e = read_bounded(Path::new("/dev/zero"), 1 << 20).unwrap_err();
            assert!(e.to_string().contains("not a regular file"), "{e}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
