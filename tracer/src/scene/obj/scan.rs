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
        if let Err(message) = scan_line(&mut out, line, line_no, start, display) {
            out.error = Some(ObjError::Parse { path: display.to_string(), line: line_no, message });
            break;
        }
    }
    out
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
