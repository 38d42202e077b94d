//! The OBJ lexer: one pass over a run of whole lines of an OBJ file (a chunk, see
//! `parallel`), which validates every statement (numbers, index ranges, face sizes) with
//! line numbers and reads the file's vertex data and faces.
//!
//! It is the only OBJ parser: tobj reports neither line numbers nor smoothing groups and
//! parses serially, so the numbers this pass must read anyway are kept (as tobj would
//! read them: `f32::from_str`, `v x y z w` divided by `w`). A chunk knows how many `v`,
//! `vt` and `vn` came before it, so indices (also relative ones) resolve here; what
//! carries over from earlier lines — the smoothing group and the material — is recorded
//! as "as at the chunk's start" and settled when the chunks are merged in file order.
//!
//! The lines that make up nearly all of a large file (`v x y z`, `f` with whole
//! corners) take a quick path first (`scan_common`): ASCII words, the same number
//! parsers, and any line it is unsure of goes to the general path (`scan_line`).

use glam::{Vec2, Vec3};

use super::ObjError;
use crate::scene::NONE;

/// One face corner: 0-based indices into the file's `v`, `vt` and `vn` lists.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct Corner {
    pub v: u32,
    /// `NONE` when the corner has no texture coordinate.
    pub vt: u32,
    /// `NONE` when the corner has no normal.
    pub vn: u32,
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) struct FaceInfo {
    /// Index of the first corner in [`ObjScan::corners`]. 32 bits, as the corner count:
    /// a file has millions of faces, and this is 16 bytes a face instead of 32 (a
    /// larger file is refused, see [`corner_index`]).
    pub first: u32,
    pub len: u32,
    /// Smoothing group id (0 = no smoothing). In a [`Chunk`]: 0 for the group in force
    /// at the chunk's start, else 1 + the index of the chunk's `s` statement.
    pub smoothing: u32,
    /// Index into [`ObjScan::material_names`], or `NONE` when no `usemtl` is active. In a
    /// [`Chunk`]: 0 for the material at the chunk's start, else 1 + the index of the
    /// chunk's `usemtl` statement.
    pub material: u32,
}

impl FaceInfo {
    /// The face's corners' indices in [`ObjScan::corners`].
    #[inline]
    pub fn corners(&self) -> std::ops::Range<usize> {
        self.first as usize..self.first as usize + self.len as usize
    }
}

/// A count of corners as a [`FaceInfo`] holds it; `None` past 32 bits (some 4 billion
/// corners, more than a 4 GiB file can hold).
pub(super) fn corner_index(n: usize) -> Option<u32> {
    u32::try_from(n).ok()
}

/// A whole OBJ file, scanned.
#[derive(Debug, Default, PartialEq)]
pub(super) struct ObjScan {
    pub positions: Vec<Vec3>,
    pub texcoords: Vec<Vec2>,
    pub normals: Vec<Vec3>,
    pub corners: Vec<Corner>,
    pub faces: Vec<FaceInfo>,
    /// Distinct `usemtl` names, with the line of their first use.
    pub material_names: Vec<(String, usize)>,
    /// `mtllib` statements: line and argument.
    pub mtllibs: Vec<(usize, String)>,
    pub warnings: Vec<String>,
}

/// Where a chunk starts: its first line's number and the elements before it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct Start {
    pub line: usize,
    pub v: usize,
    pub vt: usize,
    pub vn: usize,
}

/// What one chunk of lines holds.
#[derive(Debug, Default)]
pub(super) struct Chunk {
    pub positions: Vec<Vec3>,
    pub texcoords: Vec<Vec2>,
    pub normals: Vec<Vec3>,
    pub corners: Vec<Corner>,
    /// `first` counts from this chunk's first corner; see [`FaceInfo`] for the state.
    pub faces: Vec<FaceInfo>,
    /// The chunk's `s` statements in order (0 = off).
    pub smoothing: Vec<u64>,
    /// The chunk's `usemtl` statements in order: a name and its line, or none.
    pub materials: Vec<Option<(String, usize)>>,
    pub mtllibs: Vec<(usize, String)>,
    /// Warnings given on the way, in order.
    pub warnings: Vec<String>,
    /// Unsupported keywords (shortened) with their count and first line, in order of
    /// first appearance.
    pub ignored: Vec<(String, usize, usize)>,
    /// Faces of fewer than 3 vertices, `l` and `p` elements, and the first line of any.
    pub arealess: (usize, usize, Option<usize>),
    /// The chunk's first error: nothing after it was read.
    pub error: Option<ObjError>,
}

/// Statements recognised and used; anything else is ignored with a summary warning.
fn is_supported(keyword: &str) -> bool {
    matches!(keyword, "v" | "vt" | "vn" | "f" | "s" | "g" | "o" | "usemtl" | "mtllib")
}

/// The statement of a line: its keyword (the first word, after any indentation).
pub(super) fn keyword(line: &str) -> &str {
    line.split_whitespace().next().unwrap_or("")
}

/// The first `N` words, without allocating.
fn first_words<'a, const N: usize>(mut words: impl Iterator<Item = &'a str>) -> [Option<&'a str>; N] {
    std::array::from_fn(|_| words.next())
}

/// The first three of `words` as finite numbers; `needs` says what is missing when there
/// are fewer (counting them first, so that "needs 3, found 2" wins over a bad number).
fn three(words: &[Option<&str>], what: &str, needs: &str) -> Result<[f32; 3], String> {
    let found = words.iter().flatten().count();
    if found < 3 {
        return Err(format!("{needs}, found {found}"));
    }
    let mut xyz = [0.0f32; 3];
    for (c, tok) in xyz.iter_mut().zip(words.iter().flatten()) {
        *c = parse_coord(tok, what)?;
    }
    Ok(xyz)
}

/// Cuts a trailing `# comment`.
fn strip_comment(s: &str) -> &str {
    match s.find('#') {
        Some(i) => &s[..i],
        None => s,
    }
}

/// Parses a finite float.
fn parse_coord(tok: &str, what: &str) -> Result<f32, String> {
    let x: f32 = tok.parse().map_err(|_| format!("bad number '{}' in {what}", shorten(tok)))?;
    if !x.is_finite() {
        return Err(format!("non-finite number '{}' in {what}", shorten(tok)));
    }
    Ok(x)
}

/// Clips user text quoted in messages.
pub(super) fn shorten(s: &str) -> String {
    const MAX: usize = 40;
    if s.chars().count() <= MAX { s.to_string() } else { format!("{}...", s.chars().take(MAX).collect::<String>()) }
}

/// Resolves one OBJ index (1-based, or negative = relative to the `count` elements so far).
fn resolve_index(tok: &str, count: usize, corner: &str, what: &str, plural: &str) -> Result<u32, String> {
    let x: i64 =
        tok.parse().map_err(|_| format!("bad index '{}' in face vertex '{}'", shorten(tok), shorten(corner)))?;
    if x == 0 {
        return Err(format!("{what} index 0 is invalid (OBJ indices start at 1)"));
    }
    let idx = if x > 0 { x - 1 } else { count as i64 + x };
    if idx < 0 || idx >= count as i64 {
        return Err(format!("{what} index {x} out of range ({count} {plural})"));
    }
    u32::try_from(idx).map_err(|_| format!("{what} index {x} too large"))
}

fn parse_corner(tok: &str, counts: (usize, usize, usize)) -> Result<Corner, String> {
    let mut parts = tok.split('/');
    let (v_tok, vt_tok, vn_tok) = (parts.next().unwrap_or(""), parts.next(), parts.next());
    if parts.next().is_some() {
        return Err(format!("bad face vertex '{}' (expected v, v/vt, v//vn or v/vt/vn)", shorten(tok)));
    }
    if v_tok.is_empty() {
        return Err(format!("face vertex '{}' has no position index", shorten(tok)));
    }
    let v = resolve_index(v_tok, counts.0, tok, "face", "vertices")?;
    let vt = match vt_tok {
        Some(s) if !s.is_empty() => resolve_index(s, counts.1, tok, "texture coordinate", "texture coordinates")?,
        _ => NONE,
    };
    let vn = match vn_tok {
        Some(s) if !s.is_empty() => resolve_index(s, counts.2, tok, "normal", "normals")?,
        _ => NONE,
    };
    Ok(Corner { v, vt, vn })
}

/// Scans whole lines starting at `start`; errors name `display` and the line.
pub(super) fn scan_chunk(text: &str, start: Start, display: &str) -> Chunk {
    let mut out = Chunk::default();
    for (i, raw) in text.split('\n').enumerate() {
        let line_no = start.line + i;
        let line = raw.strip_suffix('\r').unwrap_or(raw);
        if scan_common(&mut out, line, start) {
            continue;
        }
        if let Err(message) = scan_line(&mut out, line, line_no, start, display) {
            out.error = Some(ObjError::Parse { path: display.to_string(), line: line_no, message });
            break;
        }
    }
    out
}

/// Whitespace as `char::is_whitespace` has it, among ASCII bytes (vertical tab
/// included, unlike `u8::is_ascii_whitespace`).
#[inline]
pub(super) fn is_ascii_space(b: u8) -> bool {
    matches!(b, b'\t' | b'\n' | 0x0B | 0x0C | b'\r' | b' ')
}

/// The words of `s` between ASCII whitespace bytes. Where `s` holds only ASCII
/// whitespace these are `split_whitespace`'s words; a word that holds other whitespace
/// is no number or index, so the callers below fall back on the general path.
fn ascii_words(s: &str) -> impl Iterator<Item = &str> {
    // Cuts at ASCII bytes fall on character boundaries, so the slices are valid.
    s.split(|c: char| c.is_ascii() && is_ascii_space(c as u8)).filter(|w| !w.is_empty())
}

/// An index as [`resolve_index`] resolves it, or `None` where that gives an error.
#[inline]
fn resolve_quick(tok: &str, count: usize) -> Option<u32> {
    let x: i64 = tok.parse().ok()?;
    let idx = if x > 0 { x - 1 } else { count as i64 + x };
    (x != 0 && idx >= 0 && idx < count as i64).then_some(idx).and_then(|i| u32::try_from(i).ok())
}

/// A face corner as [`parse_corner`] reads it, or `None` where that gives an error.
#[inline]
fn corner_quick(tok: &str, counts: (usize, usize, usize)) -> Option<Corner> {
    let mut parts = tok.split('/');
    let (v, vt, vn) = (parts.next()?, parts.next(), parts.next());
    if parts.next().is_some() {
        return None;
    }
    let optional = |part: Option<&str>, count| match part {
        Some(s) if !s.is_empty() => resolve_quick(s, count),
        _ => Some(NONE),
    };
    Some(Corner { v: resolve_quick(v, counts.0)?, vt: optional(vt, counts.1)?, vn: optional(vn, counts.2)? })
}

/// Reads the lines that make up nearly all of a large file — `v x y z` and `f` with
/// three or more corners, keyword first, no comment — without the general path's
/// Unicode-aware trimming and splitting, by the same number parsers, into the same
/// values. `false`, with nothing kept, for any other line or any it would reject: the
/// general path ([`scan_line`]) reads those, with its messages.
fn scan_common(out: &mut Chunk, line: &str, start: Start) -> bool {
    let bytes = line.as_bytes();
    if bytes.len() < 2 || !is_ascii_space(bytes[1]) {
        return false;
    }
    match bytes[0] {
        b'v' => {
            let mut words = ascii_words(&line[2..]);
            let xyz = [words.next(), words.next(), words.next()];
            let finite = |w: Option<&str>| w?.parse::<f32>().ok().filter(|x| x.is_finite());
            match (xyz.map(finite), words.next()) {
                ([Some(x), Some(y), Some(z)], None) => {
                    out.positions.push(Vec3::new(x, y, z));
                    true
                }
                _ => false,
            }
        }
        b'f' => {
            let first = out.corners.len();
            let counts = (start.v + out.positions.len(), start.vt + out.texcoords.len(), start.vn + out.normals.len());
            for tok in ascii_words(&line[2..]) {
                match corner_quick(tok, counts) {
                    Some(c) => out.corners.push(c),
                    None => {
                        out.corners.truncate(first);
                        return false;
                    }
                }
            }
            let len = out.corners.len() - first;
            match (corner_index(first), corner_index(len)) {
                (Some(first), Some(len)) if len >= 3 => {
                    let (smoothing, material) = (out.smoothing.len() as u32, out.materials.len() as u32);
                    out.faces.push(FaceInfo { first, len, smoothing, material });
                    true
                }
                _ => {
                    out.corners.truncate(first);
                    false
                }
            }
        }
        _ => false,
    }
}

// Long on purpose: One arm per OBJ keyword: a lexer reads best as one match.
fn scan_line(out: &mut Chunk, line: &str, line_no: usize, start: Start, display: &str) -> Result<(), String> {
    let trimmed = line.trim();
    let keyword = trimmed.split_whitespace().next().unwrap_or("");
    let rest = trimmed[keyword.len()..].trim();
    let args = || strip_comment(rest).split_whitespace();
    let counts = || (start.v + out.positions.len(), start.vt + out.texcoords.len(), start.vn + out.normals.len());
    match keyword {
        "" => {}
        k if k.starts_with('#') => {}
        "v" => {
            let toks = first_words::<5>(args());
            let mut xyz = three(&toks, "vertex", "vertex needs 3 coordinates")?;
            // 4 numbers: x y z w (divided by w, as tobj does); 6 or more: vertex colours,
            // dropped.
            if let [_, _, _, Some(w), None] = toks {
                let w = parse_coord(w, "vertex")?;
                if w == 0.0 {
                    return Err("vertex with w = 0".into());
                }
                if xyz.iter().any(|c| !(c / w).is_finite()) {
                    return Err("vertex coordinates divided by w are not finite".into());
                }
                xyz = xyz.map(|c| c / w);
            }
            out.positions.push(Vec3::from_array(xyz));
        }
        "vt" => {
            let mut toks = args();
            let u = toks.next().ok_or("texture coordinate needs at least 1 number, found 0")?;
            let u = parse_coord(u, "texture coordinate")?;
            let v = match toks.next() {
                Some(v) => parse_coord(v, "texture coordinate")?,
                None => 0.0,
            };
            out.texcoords.push(Vec2::new(u, v));
        }
        "vn" => {
            let toks = first_words::<3>(args());
            out.normals.push(Vec3::from_array(three(&toks, "normal", "normal needs 3 numbers")?));
        }
        "f" => {
            if first_words::<3>(args())[2].is_none() {
                // Real models carry stray 1- and 2-vertex faces: no area, nothing to render.
                out.arealess.0 += 1;
                out.arealess.2.get_or_insert(line_no);
                return Ok(());
            }
            let first = out.corners.len();
            let counts = counts();
            for tok in args() {
                out.corners.push(parse_corner(tok, counts)?);
            }
            let (first, len) = corner_index(first)
                .zip(corner_index(out.corners.len() - first))
                .ok_or("too many face corners for one file (more than 4 billion)")?;
            let (smoothing, material) = (out.smoothing.len() as u32, out.materials.len() as u32);
            out.faces.push(FaceInfo { first, len, smoothing, material });
        }
        "s" => {
            let arg = args().next().ok_or("smoothing group needs a number or 'off'")?;
            let group: u64 = if arg.eq_ignore_ascii_case("off") {
                0
            } else if arg.eq_ignore_ascii_case("on") {
                1
            } else {
                arg.parse().map_err(|_| format!("bad smoothing group '{}'", shorten(arg)))?
            };
            out.smoothing.push(group);
        }
        "g" | "o" => {}
        "l" | "p" => {
            out.arealess.1 += 1;
            out.arealess.2.get_or_insert(line_no);
        }
        "usemtl" => out.materials.push((!rest.is_empty()).then(|| (rest.to_string(), line_no))),
        "mtllib" => {
            if rest.is_empty() {
                out.warnings.push(format!("{display}:{line_no}: mtllib without a file name, ignored"));
            } else {
                out.mtllibs.push((line_no, rest.to_string()));
            }
        }
        other => {
            debug_assert!(!is_supported(other));
            let key = shorten(other);
            match out.ignored.iter_mut().find(|(k, _, _)| *k == key) {
                Some(entry) => entry.1 += 1,
                None => out.ignored.push((key, 1, line_no)),
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Numbers and indices the quick path takes, and words it must not.
    const COMMON: &[&str] = &["1", "2", "-1", "+2", "7", "-6", "1.5", "-0.0", "3/1", "1//2", "2/2/2", "-1/-1/-1"];
    const ODD: &[&str] = &[
        "v",
        "vt",
        "f",
        "0",
        "1/3/",
        "1/1/1/1",
        "/1",
        "1/",
        "x",
        "inf",
        "NaN",
        "1e39",
        "#",
        "#c",
        "3#",
        "1,2",
        "\u{a0}",
        "99999999999999999999",
        "4294967297",
    ];
    const SPACES: &[&str] = &["\t", "\u{b}", "\u{c}", "\r", "\u{a0}", "\u{3000}", "  "];

    /// A word, mostly a common one, and the space before it, mostly one blank.
    fn word() -> impl Strategy<Value = (&'static str, &'static str)> {
        let w = prop_oneof![4 => prop::sample::select(COMMON), 1 => prop::sample::select(ODD)];
        let s = prop_oneof![6 => Just(" "), 1 => prop::sample::select(SPACES)];
        (w, s)
    }

    /// A chunk that has read 5 positions, 2 texture coordinates and 2 normals after
    /// `start`'s 1, 1 and 1, and one face.
    fn chunk() -> (Chunk, Start) {
        let mut c = Chunk { positions: vec![Vec3::ONE; 5], ..Chunk::default() };
        c.texcoords = vec![Vec2::ZERO; 2];
        c.normals = vec![Vec3::Z; 2];
        c.corners = vec![Corner { v: 0, vt: NONE, vn: NONE }; 3];
        c.faces.push(FaceInfo { first: 0, len: 3, smoothing: 0, material: 0 });
        (c, Start { line: 1, v: 1, vt: 1, vn: 1 })
    }

    type Read = (Vec<Vec3>, Vec<Corner>, Vec<FaceInfo>);

    fn read(c: &Chunk) -> Read {
        (c.positions.clone(), c.corners.clone(), c.faces.clone())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(4000))]

        /// The quick path takes a line only when the general path reads it without an
        /// error and into the same values; a line it refuses leaves the chunk as it was.
        #[test]
        fn the_quick_path_reads_as_the_general_path(
            lead in 0usize..3,
            words in prop::collection::vec(word(), 0..6),
        ) {
            let mut line = ["", "v", "f"][lead].to_string();
            for (w, s) in words {
                line.push_str(s);
                line.push_str(w);
            }
            let (mut quick, start) = chunk();
            let before = read(&quick);
            let taken = scan_common(&mut quick, &line, start);
            let (mut general, _) = chunk();
            let result = scan_line(&mut general, &line, 7, start, "t.obj");
            if taken {
                prop_assert!(result.is_ok(), "{line:?}: {result:?}");
                prop_assert_eq!(read(&quick), read(&general), "{:?}", line);
            } else {
                prop_assert_eq!(read(&quick), before, "{:?}", line);
            }
        }
    }

    #[test]
    fn the_quick_path_takes_the_common_lines() {
        for line in ["v 1 2.5 -3", "v\t1 2 3 ", "f 1 2 3", "f 1/1 2/2 3/1", "f 1//1 2//2 3//2 4//1", "f -1 -2 -3"] {
            let (mut c, start) = chunk();
            assert!(scan_common(&mut c, line, start), "{line:?}");
        }
        for line in ["v 1 2 3 1", "v 1 2 3 # c", "f 1 2", "f 1 2 9", " v 1 2 3", "v 1\u{a0}2 3", "f 1 2 3\u{b}#"] {
            let (mut c, start) = chunk();
            assert!(!scan_common(&mut c, line, start), "{line:?}");
        }
    }
}
