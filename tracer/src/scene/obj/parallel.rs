//! Scanning an OBJ file on all threads: the text is cut at line boundaries into chunks,
//! a quick count tells each chunk where it starts (its first line and the `v`, `vt`,
//! `vn` before it), the chunks are scanned at once, and their parts are joined in file
//! order. The result — and the first error, by line — is the one a single pass over
//! the whole file gives, for any cut (`tests` checks every cut of small files).

use std::collections::HashMap;

use rayon::prelude::*;

use super::ObjError;
use super::scan::{Chunk, FaceInfo, ObjScan, Start, is_ascii_space, keyword, scan_chunk};
use crate::scene::NONE;

/// Files below this are scanned in one piece; larger ones in chunks of at least this.
const MIN_CHUNK_BYTES: usize = 1 << 20;

/// Scans `text` (already valid UTF-8). Errors name `display` and the line.
pub(super) fn scan(text: &str, display: &str) -> Result<ObjScan, ObjError> {
    scan_in(text, display, chunk_bytes_for(text.len()))
}

/// [`scan`], cut into chunks of about `chunk_bytes`.
pub(super) fn scan_in(text: &str, display: &str, chunk_bytes: usize) -> Result<ObjScan, ObjError> {
    let (chunks, _) = scan_from(text, Start { line: 1, ..Start::default() }, display, chunk_bytes);
    join(chunks, display)
}

/// The chunks of `text`, which begins at `start` (its first line's number and the
/// elements before it), scanned at once, in file order; and where the text after
/// `text` starts.
pub(super) fn scan_from(text: &str, start: Start, display: &str, chunk_bytes: usize) -> (Vec<Chunk>, Start) {
    let chunks = cut(text, chunk_bytes.max(1));
    let counts: Vec<Start> = chunks.par_iter().map(|c| count(c)).collect();
    let mut starts = Vec::with_capacity(chunks.len());
    let mut at = start;
    for c in &counts {
        starts.push(at);
        at = Start { line: at.line + c.line, v: at.v + c.v, vt: at.vt + c.vt, vn: at.vn + c.vn };
    }
    let scanned = chunks.par_iter().zip(&starts).map(|(text, &start)| scan_chunk(text, start, display)).collect();
    (scanned, at)
}

/// Chunk size for [`scan_from`] on `bytes` of text: a few pieces per thread, none
/// smaller than [`MIN_CHUNK_BYTES`].
pub(super) fn chunk_bytes_for(bytes: usize) -> usize {
    let pieces = (rayon::current_num_threads() * 4).min(bytes / MIN_CHUNK_BYTES).max(1);
    bytes.div_ceil(pieces)
}

/// `text` cut into runs of whole lines of about `bytes` each (each but the last ends
/// with its newline).
fn cut(text: &str, bytes: usize) -> Vec<&str> {
    let mut out = Vec::with_capacity(text.len() / bytes + 1);
    let mut rest = text;
    while rest.len() > bytes {
        let end = match rest.as_bytes()[bytes..].iter().position(|&b| b == b'\n') {
            Some(i) => bytes + i + 1,
            None => rest.len(),
        };
        let (chunk, tail) = rest.split_at(end);
        out.push(chunk);
        rest = tail;
    }
    if !rest.is_empty() || out.is_empty() {
        out.push(rest);
    }
    out
}

/// A chunk's newlines and its `v`, `vt` and `vn` statements.
fn count(text: &str) -> Start {
    let mut n = Start::default();
    for line in text.split('\n') {
        n.line += 1;
        match quick_keyword(line).unwrap_or_else(|| keyword(line)) {
            "v" => n.v += 1,
            "vt" => n.vt += 1,
            "vn" => n.vn += 1,
            _ => {}
        }
    }
    // `split` yields one more piece than there are newlines.
    n.line -= 1;
    n
}

/// A line's keyword as far as [`count`] needs it, from its first bytes: `v`, `vt`,
/// `vn`, or "" for any other keyword; `None` (ask [`keyword`]) when the line starts
/// with whitespace or with, or after its first one or two letters has, a byte outside
/// ASCII (which may be whitespace ending the word).
fn quick_keyword(line: &str) -> Option<&'static str> {
    let b = line.as_bytes();
    let ends = |i: usize| b.get(i).map_or(Some(true), |&c| c.is_ascii().then(|| is_ascii_space(c)));
    match b.first() {
        None => Some(""),
        Some(&c) if !c.is_ascii() || is_ascii_space(c) => None,
        Some(b'v') => match b.get(1) {
            Some(&k @ (b't' | b'n')) => Some(if ends(2)? { if k == b't' { "vt" } else { "vn" } } else { "" }),
            _ => Some(if ends(1)? { "v" } else { "" }),
        },
        // Any other first letter starts a keyword that is none of these.
        Some(_) => Some(""),
    }
}

/// How a chunk's faces are numbered in the file: their first corner from the chunk's
/// base, and their smoothing group and material (in a chunk, 0 for the one in force at
/// its start, else 1 + the index of the chunk's own statement) as the file's.
struct FaceMap {
    corner_base: u32,
    smoothing: Vec<u32>,
    materials: Vec<u32>,
    /// The smoothing group and material in force at the chunk's start.
    before: (u32, u32),
}

impl FaceMap {
    fn apply(&self, f: &FaceInfo) -> FaceInfo {
        let at = |own: &[u32], k: u32, before: u32| if k == 0 { before } else { own[k as usize - 1] };
        FaceInfo {
            // The file's corners fit 32 bits (checked before joining).
            first: self.corner_base + f.first,
            smoothing: at(&self.smoothing, f.smoothing, self.before.0),
            material: at(&self.materials, f.material, self.before.1),
            ..*f
        }
    }
}

/// What carries from chunk to chunk while they are joined: the settled state of the
/// file so far (`out` holds its names, libraries and warnings, and — when joining — its
/// vertex data and faces).
#[derive(Default)]
pub(super) struct Joined {
    pub out: ObjScan,
    smoothing_ids: HashMap<u64, u32>,
    material_ids: HashMap<String, u32>,
    /// The smoothing group and material in force.
    smoothing: u32,
    material: u32,
    ignored: Vec<(String, usize, usize)>,
    arealess: (usize, usize, Option<usize>),
}

/// The chunks' parts in file order, as one pass would have made them. What carries from
/// chunk to chunk (smoothing groups, materials, warnings) is settled in order; the bulk
/// — vertex data, corners and faces, hundreds of megabytes for ten million triangles —
/// is then copied into place on all threads.
fn join(mut chunks: Vec<Chunk>, display: &str) -> Result<ObjScan, ObjError> {
    let corners: usize = chunks.iter().map(|c| c.corners.len()).sum();
    if super::scan::corner_index(corners).is_none() {
        return Err(ObjError::Parse {
            path: display.to_string(),
            line: 1,
            message: format!("{corners} face corners: more than one file may hold (4 billion)"),
        });
    }
    let mut j = Joined::new();
    let mut maps = Vec::with_capacity(chunks.len());
    let mut corner_base = 0u32;
    for c in &mut chunks {
        maps.push(j.settle_state(c, corner_base));
        // The file's corners fit 32 bits (checked above).
        corner_base += c.corners.len() as u32;
        if let Some(e) = c.error.take() {
            return Err(e);
        }
    }
    let out = &mut j.out;
    out.positions = concat(parts(&mut chunks, |c| &mut c.positions), |_, p| p);
    out.texcoords = concat(parts(&mut chunks, |c| &mut c.texcoords), |_, t| t);
    out.normals = concat(parts(&mut chunks, |c| &mut c.normals), |_, n| n);
    out.corners = concat(parts(&mut chunks, |c| &mut c.corners), |_, c| c);
    out.faces = concat(parts(&mut chunks, |c| &mut c.faces), |k, f| maps[k].apply(&f));
    Ok(j.finish(display))
}

/// Each chunk's `part`, taken out of it.
fn parts<T>(chunks: &mut [Chunk], part: impl Fn(&mut Chunk) -> &mut Vec<T>) -> Vec<Vec<T>> {
    chunks.iter_mut().map(|c| std::mem::take(part(c))).collect()
}

/// The parts one after the other in one vector, each element mapped by `f` (given its
/// part's index), written on all threads. Each part is freed once copied, so that the
/// file's data is not held twice.
fn concat<S: Send, T: Send>(parts: Vec<Vec<S>>, f: impl Fn(usize, S) -> T + Sync) -> Vec<T> {
    let total = parts.iter().map(Vec::len).sum();
    let mut out: Vec<T> = Vec::with_capacity(total);
    let mut rest = &mut out.spare_capacity_mut()[..total];
    let mut places = Vec::with_capacity(parts.len());
    for (k, part) in parts.into_iter().enumerate() {
        let (here, after) = rest.split_at_mut(part.len());
        places.push((k, here, part));
        rest = after;
    }
    places.into_par_iter().for_each(|(k, here, part)| {
        for (slot, x) in here.iter_mut().zip(part) {
            slot.write(f(k, x));
        }
    });
    // SAFETY: the places cut `out`'s first `total` slots into one run per part, of that
    // part's length, and each slot of each run was written just above.
    unsafe { out.set_len(total) };
    out
}

/// Unsupported keywords listed in the warning; later ones are not named.
const IGNORED_LISTED: usize = 16;

impl Joined {
    pub fn new() -> Self {
        Self { material: NONE, ..Self::default() }
    }

    /// Settles a chunk's state against the file's so far: its faces with the file's
    /// smoothing group and material numbers (and their first corner counted from
    /// `corner_base`); its libraries, warnings and summaries join the file's. The chunk
    /// keeps its vertex data, corners and error.
    pub fn settle(&mut self, c: &mut Chunk, corner_base: u32) -> Vec<FaceInfo> {
        let map = self.settle_state(c, corner_base);
        c.faces.iter().map(|f| map.apply(f)).collect()
    }

    /// [`Self::settle`] but for the faces: how to number them.
    fn settle_state(&mut self, c: &mut Chunk, corner_base: u32) -> FaceMap {
        // Smoothing groups are numbered, and materials listed, in order of first use.
        let smoothing: Vec<u32> = c
            .smoothing
            .iter()
            .map(|&g| {
                let next = self.smoothing_ids.len() as u32 + 1;
                if g == 0 { 0 } else { *self.smoothing_ids.entry(g).or_insert(next) }
            })
            .collect();
        let materials: Vec<u32> = std::mem::take(&mut c.materials)
            .into_iter()
            .map(|m| match m {
                None => NONE,
                Some((name, line)) => {
                    let next = self.out.material_names.len() as u32;
                    *self.material_ids.entry(name).or_insert_with_key(|name| {
                        self.out.material_names.push((name.clone(), line));
                        next
                    })
                }
            })
            .collect();
        let map = FaceMap { corner_base, smoothing, materials, before: (self.smoothing, self.material) };
        self.smoothing = map.smoothing.last().copied().unwrap_or(self.smoothing);
        self.material = map.materials.last().copied().unwrap_or(self.material);
        self.out.mtllibs.append(&mut c.mtllibs);
        self.out.warnings.append(&mut c.warnings);
        for (key, n, line) in c.ignored.drain(..) {
            match self.ignored.iter().position(|(k, _, _)| *k == key) {
                Some(i) => self.ignored[i].1 += n,
                None if self.ignored.len() < IGNORED_LISTED => self.ignored.push((key, n, line)),
                None => {}
            }
        }
        self.arealess.0 += c.arealess.0;
        self.arealess.1 += c.arealess.1;
        self.arealess.2 = self.arealess.2.or(c.arealess.2);
        map
    }

    /// The whole file's scan, with its summary warnings.
    pub fn finish(self, display: &str) -> ObjScan {
        let Joined { mut out, ignored, arealess, .. } = self;
        if let (faces, lines, Some(first)) = arealess {
            out.warnings.push(format!(
                "{display}: skipped {faces} faces with fewer than 3 vertices and {lines} line or point elements \
                 (l, p), which have no area to render (first on line {first})"
            ));
        }
        if !ignored.is_empty() {
            let list: Vec<String> =
                ignored.iter().map(|(k, n, l)| format!("'{k}' ({n}x, first on line {l})")).collect();
            out.warnings.push(format!("{display}: ignored unsupported statements: {}", list.join(", ")));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Files that exercise everything that carries across lines: relative indices,
    /// smoothing groups and materials set before a cut, ignored statements, arealess
    /// faces, warnings, and errors of each kind (the first one wins).
    const FILES: &[&str] = &[
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0 2\nvt 0.5\nvt 1 1\nvn 0 0 1\nusemtl a\ns 3\nf 1/1/1 2/2/1 3/1/1\n\
         f -1 -2 -3\ns off\nf 1 2 4\nusemtl b\nusemtl a\ns 9\ns 3\nf 4 3 2\nusemtl\nf 1 2 3\n",
        "# header\r\nmtllib m.mtl\nmtllib\nv 0 0 0 # comment\nv 1 0 0\nv 0 1 0\nf 1 2\nl 1 2\np 1\nfoo 1\nbar\nfoo 2\n\
         g one\no two\nf 1 2 3 # tail\n\nv 0 0 1\nf 1 2 3 4\nbaz\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 5\nv 1 2\n",
        "v 0 0 0\nv 1 0 0\nv x 1 0\nf 1 2 4\n",
        "v 0 0 0\nvn 1\nf 1 1 1\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/2 2 3\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1//1 2//1 3//1\n",
        "v 1 1 1 0\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\ns x\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1/1/1 2 3\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n",
        "vt\n",
        "",
        "\n\n\n",
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3",
    ];

    /// Every cut gives what one pass gives: the same scan, or the same first error.
    #[test]
    fn every_cut_scans_as_one_pass() {
        let mut errors = 0;
        for text in FILES {
            let whole = scan_in(text, "t.obj", usize::MAX).map_err(|e| e.to_string());
            errors += usize::from(whole.is_err());
            for bytes in 1..=text.len() {
                let cut = scan_in(text, "t.obj", bytes).map_err(|e| e.to_string());
                assert_eq!(cut, whole, "{text:?} cut every {bytes} bytes");
            }
        }
        assert!(errors >= 8, "the error files are errors ({errors})");
    }

    #[test]
    fn one_pass_reads_what_the_file_says() {
        let s = scan_in(FILES[0], "t.obj", usize::MAX).unwrap();
        assert_eq!(s.positions[3], glam::Vec3::new(0.5, 0.5, 0.0), "x y z w is divided by w");
        assert_eq!(s.texcoords[0], glam::Vec2::new(0.5, 0.0), "vt u is vt u 0");
        assert_eq!(s.faces.len(), 5);
        let names: Vec<&str> = s.material_names.iter().map(|(n, _)| n.as_str()).collect();
        assert_eq!(names, ["a", "b"]);
        let state: Vec<(u32, u32)> = s.faces.iter().map(|f| (f.smoothing, f.material)).collect();
        assert_eq!(state, [(1, 0), (1, 0), (0, 0), (1, 0), (1, NONE)]);
        assert_eq!(s.corners[3..6].iter().map(|c| c.v).collect::<Vec<_>>(), [3, 2, 1], "relative indices");
        let w = scan_in(FILES[1], "t.obj", usize::MAX).unwrap().warnings;
        assert_eq!(w.len(), 3, "{w:?}");
        assert!(w[1].contains("skipped 1 faces") && w[1].contains("2 line or point") && w[1].contains("line 7"));
        assert!(w[2].contains("'foo' (2x, first on line 10), 'bar' (1x, first on line 11), 'baz'"), "{w:?}");
    }

    #[test]
    fn cuts_fall_after_newlines() {
        assert_eq!(cut("ab\ncd\nef", 1), ["ab\n", "cd\n", "ef"]);
        assert_eq!(cut("ab\ncd\n", 4), ["ab\ncd\n"]);
        assert_eq!(cut("", 4), [""]);
        assert_eq!(count("v 1\n vt 2\nvn\nf\n"), Start { line: 4, v: 1, vt: 1, vn: 1 });
    }
}

#[cfg(test)]
mod keyword_tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4000))]

        /// Where the quick look answers, it counts as the keyword does.
        #[test]
        fn the_quick_keyword_counts_as_the_keyword(
            parts in prop::collection::vec(prop::sample::select(&[
                "v", "t", "n", "f", "x", "#", " ", "\t", "\u{b}", "\u{c}", "\r", "\u{a0}", "\u{3000}", "é",
            ][..]), 0..5),
        ) {
            let line: String = parts.concat();
            let slow = match keyword(&line) {
                k @ ("v" | "vt" | "vn") => k,
                _ => "",
            };
            if let Some(quick) = quick_keyword(&line) {
                prop_assert_eq!(quick, slow, "{:?}", line);
            }
        }
    }
}
