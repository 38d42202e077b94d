//! A light line-based pass over the OBJ text, run before tobj parses it.
//!
//! tobj reports neither line numbers nor smoothing groups, so this pass validates every
//! statement (numbers, index ranges, face sizes) with line numbers, records per face its
//! line, smoothing group, `usemtl` name and resolved global indices, and writes a
//! sanitised copy of the text (same line count) containing only the statements tobj
//! must see, in a form it accepts (comments stripped, `vt u` completed to `vt u 0`, vertex
//! colours dropped, `l` lines removed, ...).

use std::collections::HashMap;

use super::ObjError;
use crate::scene::NONE;

/// One face corner: 0-based indices into the file's `v`, `vt` and `vn` lists.
#[derive(Clone, Copy, Debug)]
pub(super) struct Corner {
    pub v: u32,
    /// `NONE` when the corner has no texture coordinate.
    pub vt: u32,
    /// `NONE` when the corner has no normal.
    pub vn: u32,
}

#[derive(Clone, Copy, Debug)]
pub(super) struct FaceInfo {
    /// 1-based line number of the `f` statement.
    pub line: usize,
    /// Index of the first corner in [`ObjScan::corners`].
    pub first: usize,
    pub len: usize,
    /// Smoothing group id (0 = no smoothing).
    pub smoothing: u32,
    /// Index into [`ObjScan::material_names`], or `NONE` when no `usemtl` is active.
    pub material: u32,
}

#[derive(Debug, Default)]
pub(super) struct ObjScan {
    /// Sanitised text for tobj, with the same line numbering as the input.
    pub text: String,
    pub corners: Vec<Corner>,
    pub faces: Vec<FaceInfo>,
    /// Distinct `usemtl` names, with the line of their first use.
    pub material_names: Vec<(String, usize)>,
    /// `mtllib` statements: line and argument.
    pub mtllibs: Vec<(usize, String)>,
    pub num_v: usize,
    pub num_vt: usize,
    pub num_vn: usize,
    pub warnings: Vec<String>,
}

/// Statements recognised and used; anything else is ignored with a summary warning.
fn is_supported(keyword: &str) -> bool {
    matches!(keyword, "v" | "vt" | "vn" | "f" | "s" | "g" | "o" | "usemtl" | "mtllib")
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
    let parts: Vec<&str> = tok.split('/').collect();
    if parts.len() > 3 {
        return Err(format!("bad face vertex '{}' (expected v, v/vt, v//vn or v/vt/vn)", shorten(tok)));
    }
    let v_tok = parts[0];
    if v_tok.is_empty() {
        return Err(format!("face vertex '{}' has no position index", shorten(tok)));
    }
    let v = resolve_index(v_tok, counts.0, tok, "face", "vertices")?;
    let vt = match parts.get(1) {
        Some(s) if !s.is_empty() => resolve_index(s, counts.1, tok, "texture coordinate", "texture coordinates")?,
        _ => NONE,
    };
    let vn = match parts.get(2) {
        Some(s) if !s.is_empty() => resolve_index(s, counts.2, tok, "normal", "normals")?,
        _ => NONE,
    };
    Ok(Corner { v, vt, vn })
}

/// Scans `text` (already valid UTF-8). Errors name `display` and the line.
// Long on purpose: One arm per OBJ keyword, in one loop over the lines: a lexer reads best as one match.
pub(super) fn scan(text: &str, display: &str) -> Result<ObjScan, ObjError> {
    let mut out = ObjScan { text: String::with_capacity(text.len()), ..Default::default() };
    let mut smoothing_ids: HashMap<u64, u32> = HashMap::new();
    let mut material_ids: HashMap<String, u32> = HashMap::new();
    let mut smoothing = 0u32;
    let mut material = NONE;
    let mut ignored: Vec<(String, usize, usize)> = Vec::new(); // keyword, count, first line
    // Faces of fewer than 3 vertices, `l` and `p` elements, and the first line of any.
    let mut arealess: (usize, usize, Option<usize>) = (0, 0, None);

    for (i, raw) in text.split('\n').enumerate() {
        let line_no = i + 1;
        let line = raw.strip_suffix('\r').unwrap_or(raw);
        let err = |message: String| ObjError::Parse { path: display.to_string(), line: line_no, message };
        let trimmed = line.trim();
        let keyword = trimmed.split_whitespace().next().unwrap_or("");
        let rest = trimmed[keyword.len()..].trim();
        let args = || strip_comment(rest).split_whitespace();
        match keyword {
            "" => {}
            k if k.starts_with('#') => {}
            "v" => {
                let toks: Vec<&str> = args().collect();
                if toks.len() < 3 {
                    return Err(err(format!("vertex needs 3 coordinates, found {}", toks.len())));
                }
                let mut xyz = [0.0f32; 3];
                for (c, tok) in xyz.iter_mut().zip(&toks) {
                    *c = parse_coord(tok, "vertex").map_err(&err)?;
                }
                // 4 numbers: x y z w (tobj divides by w); 6 or more: vertex colours, dropped.
                if toks.len() == 4 {
                    let w = parse_coord(toks[3], "vertex").map_err(&err)?;
                    if w == 0.0 {
                        return Err(err("vertex with w = 0".into()));
                    }
                    if xyz.iter().any(|c| !(c / w).is_finite()) {
                        return Err(err("vertex coordinates divided by w are not finite".into()));
                    }
                    out.text.push_str(&format!("v {} {} {} {}", toks[0], toks[1], toks[2], toks[3]));
                } else {
                    out.text.push_str(&format!("v {} {} {}", toks[0], toks[1], toks[2]));
                }
                out.num_v += 1;
            }
            "vt" => {
                let toks: Vec<&str> = args().collect();
                if toks.is_empty() {
                    return Err(err("texture coordinate needs at least 1 number, found 0".into()));
                }
                for tok in toks.iter().take(2) {
                    parse_coord(tok, "texture coordinate").map_err(&err)?;
                }
                let v = toks.get(1).copied().unwrap_or("0");
                out.text.push_str(&format!("vt {} {}", toks[0], v));
                out.num_vt += 1;
            }
            "vn" => {
                let toks: Vec<&str> = args().collect();
                if toks.len() < 3 {
                    return Err(err(format!("normal needs 3 numbers, found {}", toks.len())));
                }
                for tok in toks.iter().take(3) {
                    parse_coord(tok, "normal").map_err(&err)?;
                }
                out.text.push_str(&format!("vn {} {} {}", toks[0], toks[1], toks[2]));
                out.num_vn += 1;
            }
            "f" => {
                let toks: Vec<&str> = args().collect();
                if toks.len() < 3 {
                    // Real models carry stray 1- and 2-vertex faces: no area, nothing to render.
                    arealess.0 += 1;
                    arealess.2.get_or_insert(line_no);
                    out.text.push('\n');
                    continue;
                }
                let first = out.corners.len();
                for tok in &toks {
                    let corner = parse_corner(tok, (out.num_v, out.num_vt, out.num_vn)).map_err(&err)?;
                    out.corners.push(corner);
                }
                out.faces.push(FaceInfo { line: line_no, first, len: toks.len(), smoothing, material });
                out.text.push_str("f ");
                out.text.push_str(&toks.join(" "));
            }
            "s" => {
                let arg = args().next().ok_or_else(|| err("smoothing group needs a number or 'off'".into()))?;
                let group: u64 = if arg.eq_ignore_ascii_case("off") {
                    0
                } else if arg.eq_ignore_ascii_case("on") {
                    1
                } else {
                    arg.parse().map_err(|_| err(format!("bad smoothing group '{}'", shorten(arg))))?
                };
                smoothing = if group == 0 {
                    0
                } else {
                    let next = smoothing_ids.len() as u32 + 1;
                    *smoothing_ids.entry(group).or_insert(next)
                };
            }
            "g" | "o" => out.text.push_str(trimmed),
            "l" | "p" => {
                arealess.1 += 1;
                arealess.2.get_or_insert(line_no);
            }
            "usemtl" => {
                material = if rest.is_empty() {
                    NONE
                } else {
                    let next = out.material_names.len() as u32;
                    *material_ids.entry(rest.to_string()).or_insert_with(|| {
                        out.material_names.push((rest.to_string(), line_no));
                        next
                    })
                };
            }
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
                if let Some(entry) = ignored.iter_mut().find(|(k, _, _)| *k == key) {
                    entry.1 += 1;
                } else if ignored.len() < 16 {
                    ignored.push((key, 1, line_no));
                }
            }
        }
        out.text.push('\n');
    }
    if let (faces, lines, Some(first)) = arealess {
        out.warnings.push(format!(
            "{display}: skipped {faces} faces with fewer than 3 vertices and {lines} line or point elements \
             (l, p), which have no area to render (first on line {first})"
        ));
    }
    if !ignored.is_empty() {
        let list: Vec<String> = ignored.iter().map(|(k, n, l)| format!("'{k}' ({n}x, first on line {l})")).collect();
        out.warnings.push(format!("{display}: ignored unsupported statements: {}", list.join(", ")));
    }
    Ok(out)
}
