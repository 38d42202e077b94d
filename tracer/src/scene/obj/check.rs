//! Checking an OBJ file without building it: what a coordinator needs before it hands
//! out work — the same errors and warnings as [`load_obj_as`](super::load_obj_as), the
//! materials, the triangle count and the positions auto-framing looks at — read in
//! blocks of whole lines, so that the text, the faces and the triangles are never all
//! in memory. Only the `v` positions are kept (a face may name any earlier one), 12
//! bytes each.
//!
//! Each block is scanned on all threads by the loader's own lexer (`scan`, `parallel`)
//! and settled against the file so far as the loader joins its chunks; the per-face
//! checks below are [`Builder::build`](super::Builder)'s, on the same values, so the
//! counts in its warnings are the same. `tests` compares the two on every test file
//! and every cut.

use std::io::Read;
use std::path::Path;

use glam::Vec3;

use super::parallel::{Joined, chunk_bytes_for, scan_from};
use super::scan::{Chunk, Start};
use super::{Builder, ObjError, ObjModel, area_normal, load_libraries, mtl, unusable_normal};
use crate::scene::NONE;
use crate::scene::files::{MAX_OBJ_BYTES, check_regular};

/// Text scanned at once (a block grows only to hold a longer line).
pub(super) const BLOCK_BYTES: usize = 8 << 20;

/// What checking an OBJ file finds.
#[derive(Debug)]
pub struct ObjCheck {
    /// What [`load_obj_as`](super::load_obj_as) gives — materials, textures, warnings —
    /// with an empty mesh.
    pub model: ObjModel,
    /// The triangles the mesh would hold.
    pub triangles: usize,
    /// The positions the faces use, in the order the built mesh holds them (first use).
    pub used_positions: Vec<Vec3>,
}

/// Checks the OBJ file at `path`, named `display` in errors and warnings, reading it in
/// blocks of [`BLOCK_BYTES`].
pub fn check_obj_as(path: &Path, display: &str) -> Result<ObjCheck, ObjError> {
    check_in_blocks(path, display, BLOCK_BYTES)
}

pub(super) fn check_in_blocks(path: &Path, display: &str, block_bytes: usize) -> Result<ObjCheck, ObjError> {
    let mut checker = Checker::new();
    scan_blocks(path, display, block_bytes, |c| checker.add(c))?;
    checker.finish(path.parent().unwrap_or(Path::new("")), display)
}

/// Scans the OBJ file at `path` in blocks of about `block_bytes`, giving `each` its
/// chunks in file order until one returns an error (the chunk's own, or the caller's).
/// The errors are the loader's: it decodes the whole file before it scans, so invalid
/// UTF-8 anywhere wins over a parse error before it.
pub(super) fn scan_blocks(
    path: &Path,
    display: &str,
    block_bytes: usize,
    mut each: impl FnMut(Chunk) -> Option<ObjError>,
) -> Result<(), ObjError> {
    let io = |e: std::io::Error| ObjError::Io {
        path: display.to_string(),
        message: format!("cannot read file: {}", mtl::io_reason(&e)),
    };
    check_regular(path, MAX_OBJ_BYTES).map_err(io)?;
    let mut file = std::fs::File::open(path).map_err(io)?.take(MAX_OBJ_BYTES + 1);
    let mut blocks = Blocks::default();
    let (mut start, mut first_error) = (Start { line: 1, ..Start::default() }, None);
    loop {
        let eof = blocks.fill(&mut file, block_bytes).map_err(io)?;
        if blocks.read > MAX_OBJ_BYTES {
            return Err(io(std::io::Error::other(format!("more than the {MAX_OBJ_BYTES} bytes allowed"))));
        }
        let first = blocks.offset == 0;
        let Some(text) = blocks.next_block(eof, display)? else { continue };
        // After the first error only the UTF-8 is checked.
        if first_error.is_none() {
            let text = if first { text.strip_prefix('\u{feff}').unwrap_or(text) } else { text };
            let (chunks, next) = scan_from(text, start, display, chunk_bytes_for(text.len()));
            start = next;
            first_error = chunks.into_iter().find_map(&mut each);
        }
        blocks.consume();
        if eof {
            break;
        }
    }
    first_error.map_or(Ok(()), Err)
}

/// The file's bytes, handed out as blocks of whole lines.
#[derive(Default)]
struct Blocks {
    buf: Vec<u8>,
    /// Bytes read from the file.
    read: u64,
    /// Where `buf` starts in the file, and the lines before it.
    offset: u64,
    lines: usize,
    /// The length of the block handed out.
    end: usize,
}

impl Blocks {
    /// Reads until `buf` holds `block_bytes` or the file ends; whether it ended.
    fn fill(&mut self, file: &mut impl Read, block_bytes: usize) -> std::io::Result<bool> {
        // A line longer than a block doubles what is asked for.
        let want = if self.buf.len() < block_bytes { block_bytes - self.buf.len() } else { self.buf.len() };
        let before = self.buf.len();
        let got = file.by_ref().take(want as u64).read_to_end(&mut self.buf)?;
        self.read += got as u64;
        Ok(self.buf.len() - before < want)
    }

    /// The next block of whole lines as text (at the end, the rest), or `None` when no
    /// line ends in what was read; invalid UTF-8 is the loader's error for it.
    fn next_block(&mut self, eof: bool, display: &str) -> Result<Option<&str>, ObjError> {
        self.end = match (eof, self.buf.iter().rposition(|&b| b == b'\n')) {
            (true, _) => self.buf.len(),
            (false, Some(i)) => i + 1,
            (false, None) => return Ok(None),
        };
        let block = &self.buf[..self.end];
        match std::str::from_utf8(block) {
            Ok(text) => Ok(Some(text)),
            Err(e) => {
                let at = e.valid_up_to();
                let line = self.lines + 1 + block[..at].iter().filter(|&&b| b == b'\n').count();
                Err(ObjError::Parse {
                    path: display.to_string(),
                    line,
                    message: format!(
                        "invalid UTF-8 (byte offset {}); not a text OBJ/MTL file?",
                        self.offset + at as u64
                    ),
                })
            }
        }
    }

    /// Drops the block handed out.
    fn consume(&mut self) {
        self.lines += self.buf[..self.end].iter().filter(|&&b| b == b'\n').count();
        self.offset += self.end as u64;
        self.buf.drain(..self.end);
        self.end = 0;
    }
}

/// The file's state between blocks: the scan's settled state, the positions, and the
/// loader's per-face tallies.
struct Checker {
    joined: Joined,
    positions: Vec<Vec3>,
    /// Per `vn`: it cannot shade.
    unusable: Vec<bool>,
    used: Vec<bool>,
    used_positions: Vec<Vec3>,
    /// Material slots (`NONE`: no `usemtl`) in the order triangles first use them, as
    /// the loader resolves them.
    first_use: Vec<u32>,
    slot_seen: Vec<bool>,
    default_seen: bool,
    triangles: usize,
    zero_vn_faces: usize,
    degenerate: usize,
}

impl Checker {
    fn new() -> Self {
        Self {
            joined: Joined::new(),
            positions: Vec::new(),
            unusable: Vec::new(),
            used: Vec::new(),
            used_positions: Vec::new(),
            first_use: Vec::new(),
            slot_seen: Vec::new(),
            default_seen: false,
            triangles: 0,
            zero_vn_faces: 0,
            degenerate: 0,
        }
    }

    /// Checks a chunk's faces as the loader builds them; the chunk's error, if any.
    fn add(&mut self, mut c: Chunk) -> Option<ObjError> {
        let faces = self.joined.settle(&mut c, 0);
        self.positions.extend_from_slice(&c.positions);
        self.used.resize(self.positions.len(), false);
        self.unusable.extend(c.normals.iter().map(|&n| unusable_normal(n)));
        self.slot_seen.resize(self.joined.out.material_names.len(), false);
        for face in &faces {
            let corners = &c.corners[face.corners()];
            if corners.iter().all(|k| k.vn != NONE) && corners.iter().any(|k| self.unusable[k.vn as usize]) {
                self.zero_vn_faces += 1;
            }
            for k in corners {
                if !std::mem::replace(&mut self.used[k.v as usize], true) {
                    self.used_positions.push(self.positions[k.v as usize]);
                }
            }
            for i in 1..corners.len().saturating_sub(1) {
                let p = [corners[0], corners[i], corners[i + 1]].map(|k| self.positions[k.v as usize]);
                if area_normal(p).is_none() {
                    self.degenerate += 1;
                    continue;
                }
                self.triangles += 1;
                let seen = match face.material {
                    NONE => &mut self.default_seen,
                    s => &mut self.slot_seen[s as usize],
                };
                if !std::mem::replace(seen, true) {
                    self.first_use.push(face.material);
                }
            }
        }
        c.error
    }

    /// The loader's materials and warnings, in its order: the scan's, the libraries',
    /// zero-length normals, materials as first used, degenerate triangles.
    fn finish(self, base_dir: &Path, display: &str) -> Result<ObjCheck, ObjError> {
        let scan = self.joined.finish(display);
        let mut warnings = scan.warnings.clone();
        let library = load_libraries(&scan, base_dir, display, &mut warnings)?;
        let mut b = Builder::new(&scan, display, library, warnings);
        b.note_zero_vn(self.zero_vn_faces);
        for &slot in &self.first_use {
            b.material(slot);
        }
        b.note_degenerate(self.degenerate);
        let model = ObjModel {
            mesh: Default::default(),
            materials: b.materials,
            textures: b.textures.textures,
            warnings: b.warnings,
        };
        Ok(ObjCheck { model, triangles: self.triangles, used_positions: self.used_positions })
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::scene::obj::load_obj_as;

    fn fixtures() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/obj")
    }

    /// What a check must equal: the load's error, or its materials, warnings, triangle
    /// count and used positions.
    fn same_as_load(path: &Path, block_bytes: usize) -> Result<(), String> {
        let loaded = load_obj_as(path, "t.obj");
        let checked = check_in_blocks(path, "t.obj", block_bytes);
        match (loaded, checked) {
            (Err(a), Err(b)) if a.to_string() == b.to_string() => Ok(()),
            (Ok(m), Ok(c)) => {
                let same = m.materials == c.model.materials
                    && m.warnings == c.model.warnings
                    && m.textures.len() == c.model.textures.len()
                    && m.mesh.tris.len() == c.triangles
                    && m.mesh.positions == c.used_positions
                    && c.model.mesh.tris.is_empty();
                if same { Ok(()) } else { Err(format!("{:?}\n  against {:?}", m.warnings, c.model.warnings)) }
            }
            (a, b) => Err(format!("load {:?}, check {:?}", a.map(|m| m.warnings), b.map(|c| c.model.warnings))),
        }
    }

    /// Files with everything a check must see as a load does: materials used before
    /// their library and never defined, zero `vn`, degenerate triangles, smoothing,
    /// ignored and arealess statements, a byte-order mark, and errors of each kind —
    /// also invalid UTF-8 after a parse error, which the load (decoding first) reports.
    const FILES: &[&[u8]] = &[
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0 2\nvt 0.5\nvt 1 1\nvn 0 0 1\nvn 0 0 0\nusemtl full\ns 3\n\
          f 1/1/1 2/2/1 3/1/1\nf -1 -2 -3\ns off\nf 1/1/2 2/1/2 4/1/1\nusemtl nowhere\nf 1 2 3\nusemtl full\ns 9\nf 4 3 2\n\
          usemtl\nf 1 2 3\nf 1 1 2\nmtllib materials.mtl\nusemtl transparent\nf 1 2 3 4\n",
        b"\xef\xbb\xbf# header\r\nmtllib missing.mtl\nv 0 0 0 # c\nv 1 0 0\nv 0 1 0\nf 1 2\nl 1 2\np 1\nfoo 1\n\
          g one\no two\nf 1 2 3 # tail\n\nv 0 0 1\nf 1 2 3 4\nbaz\n",
        b"mtllib textured.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nusemtl checker\nf 1/1 2/2 3/3\nusemtl lost_texture\nf 3/3 2/2 1/1\n",
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 5\nv 1 2\n",
        b"v 0 0 0\nv 1 0 0\nv x 1 0\nf 1 2 4\n\xff\n",
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nv 0 0 \xe2\x82\n",
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3",
        b"",
    ];

    /// Every block size gives what the load gives (`FILES` above and the fixtures).
    #[test]
    fn a_check_finds_what_a_load_finds_for_every_block_size() {
        let dir = std::env::temp_dir().join(format!("tilefarm-obj-check-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        for f in ["materials.mtl", "textured.mtl", "checker.png"] {
            std::fs::copy(fixtures().join(f), dir.join(f)).unwrap();
        }
        let mut paths = Vec::new();
        for (i, bytes) in FILES.iter().enumerate() {
            let p = dir.join(format!("f{i}.obj"));
            std::fs::write(&p, bytes).unwrap();
            paths.push(p);
        }
        for entry in std::fs::read_dir(fixtures()).unwrap() {
            let p = entry.unwrap().path();
            if p.extension().is_some_and(|e| e == "obj") {
                paths.push(p);
            }
        }
        let (mut errors, mut warned) = (0, 0);
        for p in &paths {
            let len = std::fs::metadata(p).unwrap().len() as usize;
            for block in (1..=len + 1).chain([BLOCK_BYTES]) {
                if let Err(e) = same_as_load(p, block) {
                    panic!("{} in blocks of {block}: {e}", p.display());
                }
            }
            match load_obj_as(p, "t.obj") {
                Err(_) => errors += 1,
                Ok(m) => warned += usize::from(!m.warnings.is_empty()),
            }
        }
        assert!(errors >= 4 && warned >= 3, "the files exercise errors ({errors}) and warnings ({warned})");
        let w = load_obj_as(&paths[0], "t.obj").unwrap().warnings;
        for words in ["zero-length vn", "unknown material 'nowhere'", "degenerate"] {
            assert!(w.iter().any(|w| w.contains(words)), "{words}: {w:?}");
        }
        let e = check_obj_as(&paths[4], "t.obj").unwrap_err().to_string();
        assert!(e.contains(":5: invalid UTF-8"), "the load decodes the whole file first: {e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
