//! A small G-code reader for the tool path of the 3D-printing nozzle (ALGORITHM §4.4).
//!
//! Only what a tool path needs is understood; everything is checked and every problem is an
//! error naming the line ([`GcodeError`]), never a panic.
//!
//! | command | meaning |
//! |---|---|
//! | `G0`, `G1` with `X Y Z E F` | linear move (travel or extrusion); `F` is modal, in units/min |
//! | `G4 P<ms>` / `G4 S<s>` | dwell: time passes, the nozzle stays, nothing is extruded |
//! | `G20` / `G21` | inches / millimetres for the coordinates, E and F that follow |
//! | `G90` / `G91` | absolute / relative coordinates (also sets the extrusion mode, as Marlin does) |
//! | `M82` / `M83` | absolute / relative extrusion (E) only |
//! | `G92 X Y Z E` | sets the current position without moving (e.g. `G92 E0`) |
//! | `G28` | homing: the named axes (all if none) are set to 0 without a timed move |
//! | other `M…`, `T…` | ignored (temperatures, fans, tool selection, …) |
//!
//! Comments (`; …` and `( … )`), line numbers (`N…`) and checksums (`*…`) are skipped.
//! Numbers follow the G-code grammar: an optional sign, digits and at most one decimal point,
//! no exponent; a number directly followed by `e`/`E` and a digit (`X1e1`) is an error rather
//! than the two words `X1 E1`.
//! Arcs (`G2`/`G3`) and any other `G` code are errors. A move extrudes when its E increment is
//! positive; a move without extrusion is travel (it does not emit). Retraction and priming
//! (E changes without motion) take their E/F time and do not emit.
//!
//! The result ([`GcodeProgram`]) is in the file's own millimetres; [`GcodeProgram::to_tool_path`]
//! maps it into the scene (scale, axes, origin) as a [`ToolPath`](super::ToolPath).
use std::fmt;
use std::path::{Path, PathBuf};

use glam::DVec3;

/// Millimetres per inch (G20).
const MM_PER_INCH: f64 = 25.4;

/// A G-code problem: where (file, 1-based line) and what.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{}:{line}: {message}", file.as_deref().map(|p| p.display().to_string()).unwrap_or_else(|| "<gcode>".into()))]
pub struct GcodeError {
    /// The file, if the text came from one.
    pub file: Option<PathBuf>,
    /// 1-based line number (0: the file as a whole, e.g. unreadable or without moves).
    pub line: usize,
    /// What is wrong.
    pub message: String,
}

/// One linear move of the program, in millimetres (after G20/G21 conversion), absolute.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GcodeMove {
    /// 1-based line of the command.
    pub line: usize,
    /// Start point \[mm\].
    pub from: DVec3,
    /// End point \[mm\] (equal to `from` for a dwell or a pure E move).
    pub to: DVec3,
    /// Duration \[s\] (length / feed rate, or E / feed rate for a pure E move, or the dwell).
    pub duration: f64,
    /// Extruded filament length ΔE \[mm\] (≤ 0 for travel and retraction).
    pub extrusion: f64,
}

impl GcodeMove {
    /// Whether the move deposits material (ΔE > 0 and the nozzle moves or dwells with E).
    pub fn extrudes(&self) -> bool {
        self.extrusion > 0.0
    }
}

/// A parsed program: its timed moves in order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GcodeProgram {
    /// The moves (dwells and pure E moves included, zero-duration moves left out).
    pub moves: Vec<GcodeMove>,
    /// The file the program came from, if any.
    pub file: Option<PathBuf>,
}

/// Parser state (modal values).
struct State {
    pos: DVec3,
    e: f64,
    feed: Option<f64>,
    unit: f64,
    relative_xyz: bool,
    relative_e: bool,
}

fn err(line: usize, message: impl Into<String>) -> GcodeError {
    GcodeError {
        file: None,
        line,
        message: message.into(),
    }
}

/// Strips comments, line numbers and checksums; returns the words `(letter, number text)`.
fn words(raw: &str, line: usize) -> Result<Vec<(char, String)>, GcodeError> {
    // Comments: `;` to the end of the line, `( … )` inline.
    let mut text = String::with_capacity(raw.len());
    let mut depth = 0usize;
    for ch in raw.chars() {
        match ch {
            ';' if depth == 0 => break,
            '(' => depth += 1,
            ')' => {
                if depth == 0 {
                    return Err(err(line, "`)` without a matching `(`"));
                }
                depth -= 1;
            }
            _ if depth == 0 => text.push(ch),
            _ => {}
        }
    }
    if depth > 0 {
        return Err(err(line, "unclosed `(` comment"));
    }
    // Checksum `*nn` ends the command.
    if let Some(i) = text.find('*') {
        text.truncate(i);
    }
    let mut out = Vec::new();
    let mut chars = text.chars().peekable();
    while let Some(&c) = chars.peek() {
        if c.is_whitespace() {
            chars.next();
            continue;
        }
        if !c.is_ascii_alphabetic() {
            return Err(err(
                line,
                format!("expected a command letter, found `{c}` in `{}`", raw.trim()),
            ));
        }
        chars.next();
        let letter = c.to_ascii_uppercase();
        let mut num = String::new();
        while let Some(&d) = chars.peek() {
            if d.is_ascii_digit() || matches!(d, '.' | '-' | '+') {
                num.push(d);
                chars.next();
            } else if d == ' ' || d == '\t' {
                // Allow `X 10` (a space between letter and number) only before the number.
                if num.is_empty() {
                    chars.next();
                } else {
                    break;
                }
            } else {
                break;
            }
        }
        // The G-code number grammar has no exponent: `X1e1` would otherwise read as `X1 E1`
        // and extrude.
        let mut ahead = chars.clone();
        if num.chars().any(|d| d.is_ascii_digit())
            && matches!(ahead.next(), Some('e' | 'E'))
            && ahead
                .next()
                .is_some_and(|d| d.is_ascii_digit() || matches!(d, '+' | '-' | '.'))
        {
            let exponent: String = chars.clone().take_while(|d| !d.is_whitespace()).collect();
            return Err(err(
                line,
                format!(
                    "`{letter}{num}{exponent}`: G-code numbers have no exponent; write the \
                     number out, or put a space before `{}` if it is the extrusion word",
                    &exponent[..1]
                ),
            ));
        }
        out.push((letter, num));
    }
    Ok(out)
}

fn number(letter: char, text: &str, line: usize) -> Result<f64, GcodeError> {
    if text.is_empty() {
        return Err(err(line, format!("`{letter}` has no number")));
    }
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(v),
        _ => Err(err(line, format!("`{letter}{text}` is not a valid number"))),
    }
}

/// Parses G-code text (see the module docs for what is understood).
pub fn parse_gcode(text: &str) -> Result<GcodeProgram, GcodeError> {
    let mut s = State {
        pos: DVec3::ZERO,
        e: 0.0,
        feed: None,
        unit: 1.0,
        relative_xyz: false,
        relative_e: false,
    };
    let mut moves = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        let ws = words(raw, line)?;
        // The command word: the first G, M or T; a leading N is a line number.
        let mut ws = ws.into_iter().peekable();
        if ws.peek().is_some_and(|(l, _)| *l == 'N') {
            let (_, num) = ws.next().unwrap_or_default();
            number('N', &num, line)?;
        }
        let Some((letter, code)) = ws.next() else {
            continue;
        };
        if letter == 'M' || letter == 'T' {
            // Parameters of M and T commands (temperatures, messages, …) are not read.
            let n = number(letter, &code, line)?;
            if letter == 'M' {
                if n == 82.0 {
                    s.relative_e = false;
                } else if n == 83.0 {
                    s.relative_e = true;
                }
            }
            continue;
        }
        if letter != 'G' {
            return Err(err(
                line,
                format!(
                    "parameter `{letter}{code}` without a command (write G0/G1 on every move line)"
                ),
            ));
        }
        let mut params: Vec<(char, f64)> = Vec::new();
        for (l, num) in ws {
            if matches!(l, 'G' | 'M' | 'T' | 'N') {
                return Err(err(
                    line,
                    format!("more than one command on a line (`{l}{num}` after `G{code}`)"),
                ));
            }
            if params.iter().any(|(p, _)| *p == l) {
                return Err(err(line, format!("parameter `{l}` given twice")));
            }
            params.push((l, number(l, &num, line)?));
        }
        let g = number('G', &code, line)?;
        let get = |c: char| params.iter().find(|(l, _)| *l == c).map(|(_, v)| *v);
        for (p, _) in &params {
            let allowed: &[char] = match g {
                _ if g == 0.0 || g == 1.0 || g == 92.0 => &['X', 'Y', 'Z', 'E', 'F'],
                _ if g == 4.0 => &['P', 'S'],
                _ if g == 28.0 => &['X', 'Y', 'Z'],
                _ => &[],
            };
            if !allowed.is_empty() && !allowed.contains(p) {
                return Err(err(
                    line,
                    format!("parameter `{p}` is not understood with G{code}"),
                ));
            }
        }
        if g == 0.0 || g == 1.0 {
            if let Some(f) = get('F') {
                if f <= 0.0 {
                    return Err(err(line, format!("feed rate F must be > 0 (got {f})")));
                }
                s.feed = Some(f * s.unit);
            }
            let mut to = s.pos;
            for (k, c) in ['X', 'Y', 'Z'].into_iter().enumerate() {
                if let Some(v) = get(c) {
                    to[k] = if s.relative_xyz {
                        s.pos[k] + v * s.unit
                    } else {
                        v * s.unit
                    };
                }
            }
            let de = match get('E') {
                Some(v) if s.relative_e => v * s.unit,
                Some(v) => v * s.unit - s.e,
                None => 0.0,
            };
            let length = (to - s.pos).length();
            let travel = if length > 0.0 { length } else { de.abs() };
            if travel > 0.0 {
                let Some(feed) = s.feed else {
                    return Err(err(
                        line,
                        "move without a feed rate: give F (units/min) on this or an earlier move",
                    ));
                };
                moves.push(GcodeMove {
                    line,
                    from: s.pos,
                    to,
                    duration: travel / (feed / 60.0),
                    extrusion: if length > 0.0 { de } else { de.min(0.0) },
                });
            }
            s.pos = to;
            s.e += de;
        } else if g == 4.0 {
            let secs = match (get('P'), get('S')) {
                (Some(p), None) => p / 1000.0,
                (None, Some(v)) => v,
                (None, None) => 0.0,
                (Some(_), Some(_)) => {
                    return Err(err(
                        line,
                        "G4 takes P (milliseconds) or S (seconds), not both",
                    ));
                }
            };
            if secs < 0.0 {
                return Err(err(line, format!("dwell time must be ≥ 0 (got {secs} s)")));
            }
            if secs > 0.0 {
                moves.push(GcodeMove {
                    line,
                    from: s.pos,
                    to: s.pos,
                    duration: secs,
                    extrusion: 0.0,
                });
            }
        } else if g == 20.0 {
            s.unit = MM_PER_INCH;
        } else if g == 21.0 {
            s.unit = 1.0;
        } else if g == 90.0 {
            s.relative_xyz = false;
            s.relative_e = false;
        } else if g == 91.0 {
            s.relative_xyz = true;
            s.relative_e = true;
        } else if g == 92.0 {
            for (k, c) in ['X', 'Y', 'Z'].into_iter().enumerate() {
                if let Some(v) = get(c) {
                    s.pos[k] = v * s.unit;
                }
            }
            if let Some(v) = get('E') {
                s.e = v * s.unit;
            }
        } else if g == 28.0 {
            let named: Vec<usize> = ['X', 'Y', 'Z']
                .into_iter()
                .enumerate()
                .filter(|(_, c)| get(*c).is_some())
                .map(|(k, _)| k)
                .collect();
            if named.is_empty() {
                s.pos = DVec3::ZERO;
            } else {
                for k in named {
                    s.pos[k] = 0.0;
                }
            }
        } else if g == 2.0 || g == 3.0 {
            return Err(err(
                line,
                format!("arc moves (G{code}) are not supported: let the slicer write G1 segments"),
            ));
        } else {
            return Err(err(line, format!("unsupported command G{code}")));
        }
    }
    if !moves.iter().any(|m| m.extrudes()) {
        return Err(err(
            0,
            "the program extrudes nothing (no G1 move with E increasing)",
        ));
    }
    Ok(GcodeProgram { moves, file: None })
}

/// Reads and parses a G-code file; errors name the file.
pub fn load_gcode(path: &Path) -> Result<GcodeProgram, GcodeError> {
    let with_file = |mut e: GcodeError| {
        e.file = Some(path.to_path_buf());
        e
    };
    let text = std::fs::read_to_string(path).map_err(|e| {
        with_file(GcodeError {
            file: None,
            line: 0,
            message: format!("cannot read the file: {e}"),
        })
    })?;
    let mut program = parse_gcode(&text).map_err(with_file)?;
    program.file = Some(path.to_path_buf());
    Ok(program)
}

impl GcodeProgram {
    /// Total time of the program \[s\].
    pub fn duration(&self) -> f64 {
        self.moves.iter().map(|m| m.duration).sum()
    }

    /// Total time spent extruding \[s\].
    pub fn extruding_time(&self) -> f64 {
        self.moves
            .iter()
            .filter(|m| m.extrudes())
            .map(|m| m.duration)
            .sum()
    }

    /// Heights (G-code Z \[mm\]) at the end of the extruding moves, sorted and deduplicated
    /// (one per printed layer for a planar slicer output).
    pub fn layer_heights(&self) -> Vec<f64> {
        let mut z: Vec<f64> = self
            .moves
            .iter()
            .filter(|m| m.extrudes())
            .map(|m| m.to.z)
            .collect();
        z.sort_by(f64::total_cmp);
        z.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
        z
    }
}

impl fmt::Display for GcodeProgram {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} moves, {:.3} s ({:.3} s extruding)",
            self.moves.len(),
            self.duration(),
            self.extruding_time()
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn words_skip_comments_and_checksums() {
        let w = words("N10 G1 X1 (comment) Y-2.5 ; rest *12", 1).unwrap();
        assert_eq!(
            w,
            vec![
                ('N', "10".into()),
                ('G', "1".into()),
                ('X', "1".into()),
                ('Y', "-2.5".into())
            ]
        );
    }
}
