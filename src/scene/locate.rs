//! Maps field paths such as `bodies[1].shape.radius` to their line and column in RON text,
//! and positions back to paths.
//!
//! serde forgets where a value came from, so after deserialization the validator only knows
//! the *path* of an invalid value. [`Locator`] re-scans the RON text with a small tokenizer
//! (it skips strings, raw strings, characters, line comments and nested block comments,
//! tracks brackets and commas) and records, for every struct field and every element of a
//! list or tuple, its path, the position where it starts and where its value ends. Struct and
//! enum-variant names before `(` (`Scene(`, `Sphere(`) are transparent: the fields of
//! `shape: Sphere(radius: 0.1)` have the path `shape.radius`.
//!
//! It is best-effort on malformed text (it never fails or panics; unknown paths fall back to
//! the nearest recorded ancestor).
use ron::error::Position;

/// One recorded field or element.
#[derive(Clone, Debug, PartialEq)]
struct Entry {
    path: String,
    start: Position,
    /// Last character of the value (inclusive); `None` if the text ended first.
    end: Option<Position>,
}

/// Field-path ↔ position index of a RON document.
#[derive(Clone, Debug, Default)]
pub struct Locator {
    entries: Vec<Entry>,
    /// Position of the first token (the top-level value), if any.
    root: Option<Position>,
}

#[derive(Clone, Debug, PartialEq)]
enum Tok {
    Ident(String),
    Punct(char),
    /// Strings, characters, numbers: values without structure.
    Atom,
}

#[derive(Clone, Debug)]
struct Token {
    tok: Tok,
    start: Position,
    end: Position,
}

struct Lexer<'a> {
    chars: std::iter::Peekable<std::str::Chars<'a>>,
    line: usize,
    col: usize,
    /// Position of the last consumed character.
    last: Position,
}

impl<'a> Lexer<'a> {
    fn new(text: &'a str) -> Self {
        Self {
            chars: text.chars().peekable(),
            line: 1,
            col: 1,
            last: Position { line: 1, col: 1 },
        }
    }

    fn pos(&self) -> Position {
        Position {
            line: self.line,
            col: self.col,
        }
    }

    fn peek(&mut self) -> Option<char> {
        self.chars.peek().copied()
    }

    fn bump(&mut self) -> Option<char> {
        let c = self.chars.next()?;
        self.last = self.pos();
        if c == '\n' {
            self.line += 1;
            self.col = 1;
        } else {
            self.col += 1;
        }
        Some(c)
    }

    /// Skips whitespace and comments.
    fn skip_trivia(&mut self) {
        loop {
            match self.peek() {
                Some(c) if c.is_whitespace() => {
                    self.bump();
                }
                Some('/') => {
                    let mut ahead = self.chars.clone();
                    ahead.next();
                    match ahead.next() {
                        Some('/') => {
                            while let Some(c) = self.bump() {
                                if c == '\n' {
                                    break;
                                }
                            }
                        }
                        Some('*') => {
                            self.bump();
                            self.bump();
                            let mut depth = 1usize;
                            while depth > 0 {
                                match self.bump() {
                                    None => return,
                                    Some('*') if self.peek() == Some('/') => {
                                        self.bump();
                                        depth -= 1;
                                    }
                                    Some('/') if self.peek() == Some('*') => {
                                        self.bump();
                                        depth += 1;
                                    }
                                    _ => {}
                                }
                            }
                        }
                        _ => return,
                    }
                }
                _ => return,
            }
        }
    }

    /// Consumes a quoted string or character body after the opening quote.
    fn quoted(&mut self, quote: char) {
        while let Some(c) = self.bump() {
            if c == '\\' {
                self.bump();
            } else if c == quote {
                return;
            }
        }
    }

    /// Consumes a raw string `r#*"..."#*` after the `r`.
    fn raw_string(&mut self) {
        let mut hashes = 0usize;
        while self.peek() == Some('#') {
            self.bump();
            hashes += 1;
        }
        if self.peek() != Some('"') {
            return;
        }
        self.bump();
        'outer: while let Some(c) = self.bump() {
            if c == '"' {
                let mut ahead = self.chars.clone();
                for _ in 0..hashes {
                    if ahead.next() != Some('#') {
                        continue 'outer;
                    }
                }
                for _ in 0..hashes {
                    self.bump();
                }
                return;
            }
        }
    }

    fn next_token(&mut self) -> Option<Token> {
        self.skip_trivia();
        let start = self.pos();
        let c = self.peek()?;
        let tok = if c == '"' || c == '\'' {
            self.bump();
            self.quoted(c);
            Tok::Atom
        } else if c == '_' || c.is_alphabetic() {
            let mut ident = String::new();
            while let Some(c) = self.peek() {
                if c == '_' || c.is_alphanumeric() {
                    ident.push(c);
                    self.bump();
                } else {
                    break;
                }
            }
            // Raw strings r"..", r#".."#, byte strings b"..", br"..", raw identifiers r#x.
            match (ident.as_str(), self.peek()) {
                ("r" | "br", Some('"' | '#')) => {
                    let mut ahead = self.chars.clone();
                    let mut n = 0;
                    while ahead.next() == Some('#') {
                        n += 1;
                    }
                    // `r#ident`: one hash, then an identifier character (not a quote).
                    let is_raw_ident = ident == "r" && n == 1 && {
                        let mut a = self.chars.clone();
                        a.nth(1).is_some_and(|c| c == '_' || c.is_alphabetic())
                    };
                    if is_raw_ident {
                        self.bump();
                        let mut raw = String::new();
                        while let Some(c) = self.peek() {
                            if c == '_' || c.is_alphanumeric() {
                                raw.push(c);
                                self.bump();
                            } else {
                                break;
                            }
                        }
                        Tok::Ident(raw)
                    } else {
                        self.raw_string();
                        Tok::Atom
                    }
                }
                ("b", Some(q @ ('"' | '\''))) => {
                    self.bump();
                    self.quoted(q);
                    Tok::Atom
                }
                _ => Tok::Ident(ident),
            }
        } else if c.is_ascii_digit() || c == '+' || c == '-' || c == '.' {
            // Numbers: digits, letters (exponents, `inf`, hex), `_`, `.`, and a sign right
            // after an exponent marker (`1e-3`).
            let mut prev = c;
            self.bump();
            while let Some(c) = self.peek() {
                let sign_of_exponent = (c == '+' || c == '-') && matches!(prev, 'e' | 'E');
                if c.is_ascii_alphanumeric() || c == '_' || c == '.' || sign_of_exponent {
                    prev = c;
                    self.bump();
                } else {
                    break;
                }
            }
            Tok::Atom
        } else {
            self.bump();
            Tok::Punct(c)
        };
        Some(Token {
            tok,
            start,
            end: self.last,
        })
    }
}

#[derive(Debug)]
struct Frame {
    /// Path of the value this container belongs to.
    path: String,
    /// Whether the container is a struct-like `(`, where `ident:` starts a field.
    struct_like: bool,
    /// Index of the current element.
    index: usize,
    /// Waiting for the start of an element.
    expect_start: bool,
    /// Entry of the current element.
    current: Option<usize>,
}

/// Whether the group opened at `tokens[open]` is closed by a token directly followed by `)`
/// (so that `(` `tokens[open]`…`)` `)` is a group holding exactly one group).
fn wraps_single_group(tokens: &[Token], open: usize) -> bool {
    let mut depth = 0i32;
    for (i, tok) in tokens.iter().enumerate().skip(open) {
        match tok.tok {
            Tok::Punct('(' | '[' | '{') => depth += 1,
            Tok::Punct(')' | ']' | '}') => {
                depth -= 1;
                if depth == 0 {
                    return matches!(
                        tokens.get(i + 1),
                        Some(Token {
                            tok: Tok::Punct(')'),
                            ..
                        })
                    );
                }
            }
            _ => {}
        }
    }
    false
}

fn child_index(path: &str, i: usize) -> String {
    format!("{path}[{i}]")
}

fn child_field(path: &str, name: &str) -> String {
    if path.is_empty() {
        name.to_string()
    } else {
        format!("{path}.{name}")
    }
}

impl Locator {
    /// Scans `text`.
    pub fn new(text: &str) -> Self {
        let mut lx = Lexer::new(text);
        let mut tokens = Vec::new();
        while let Some(t) = lx.next_token() {
            tokens.push(t);
        }
        let mut loc = Locator {
            entries: Vec::new(),
            root: None,
        };
        let mut stack: Vec<Frame> = Vec::new();
        // Path given to the next container opened at the current level.
        let mut value_path = String::new();
        let mut last_end = Position { line: 1, col: 1 };
        let mut t = 0usize;
        while t < tokens.len() {
            let token = &tokens[t];
            // `#![enable(...)]` attributes: skip the bracket group.
            if token.tok == Tok::Punct('#') && stack.is_empty() {
                let mut depth = 0i32;
                t += 1;
                while t < tokens.len() {
                    match tokens[t].tok {
                        Tok::Punct('[') => depth += 1,
                        Tok::Punct(']') => {
                            depth -= 1;
                            if depth <= 0 {
                                break;
                            }
                        }
                        _ => {}
                    }
                    t += 1;
                }
                t += 1;
                continue;
            }
            if loc.root.is_none() {
                loc.root = Some(token.start);
            }
            let is_closer = matches!(token.tok, Tok::Punct(')' | ']' | '}'));
            // `Variant((field: ...))`: a newtype variant wrapping a struct. The inner struct is
            // the variant's value, so its fields get the variant's path (`model.field`, not
            // `model[0].field`).
            if token.tok == Tok::Punct('(')
                && let Some(frame) = stack.last_mut()
                && frame.expect_start
                && frame.struct_like
                && frame.index == 0
                && t > 0
                && tokens[t - 1].tok == Tok::Punct('(')
                && wraps_single_group(&tokens, t)
            {
                frame.expect_start = false;
                let path = frame.path.clone();
                stack.push(Frame {
                    path,
                    struct_like: true,
                    index: 0,
                    expect_start: true,
                    current: None,
                });
                last_end = token.end;
                t += 1;
                continue;
            }
            if let Some(frame) = stack.last_mut()
                && frame.expect_start
                && !is_closer
                && token.tok != Tok::Punct(',')
            {
                frame.expect_start = false;
                let is_field = frame.struct_like
                    && matches!(token.tok, Tok::Ident(_))
                    && matches!(
                        tokens.get(t + 1),
                        Some(Token {
                            tok: Tok::Punct(':'),
                            ..
                        })
                    )
                    && !matches!(
                        tokens.get(t + 2),
                        Some(Token {
                            tok: Tok::Punct(':'),
                            ..
                        })
                    );
                let path = if let (true, Tok::Ident(name)) = (is_field, &token.tok) {
                    child_field(&frame.path, name)
                } else {
                    child_index(&frame.path, frame.index)
                };
                frame.current = Some(loc.entries.len());
                loc.entries.push(Entry {
                    path: path.clone(),
                    start: token.start,
                    end: None,
                });
                value_path = path;
                if is_field {
                    // Skip the name and the colon.
                    last_end = tokens[t + 1].end;
                    t += 2;
                    continue;
                }
            }
            match token.tok {
                Tok::Punct(open @ ('(' | '[' | '{')) => {
                    stack.push(Frame {
                        path: value_path.clone(),
                        struct_like: open == '(',
                        index: 0,
                        expect_start: true,
                        current: None,
                    });
                }
                Tok::Punct(')' | ']' | '}') => {
                    if let Some(frame) = stack.pop() {
                        if let Some(e) = frame.current {
                            loc.entries[e].end = Some(last_end);
                        }
                        // The closed container is the value of the parent's element.
                        value_path = stack
                            .last()
                            .and_then(|f| f.current)
                            .map(|e| loc.entries[e].path.clone())
                            .unwrap_or_default();
                    }
                }
                Tok::Punct(',') => {
                    if let Some(frame) = stack.last_mut() {
                        if let Some(e) = frame.current.take() {
                            loc.entries[e].end = Some(last_end);
                        }
                        frame.index += 1;
                        frame.expect_start = true;
                    }
                }
                _ => {}
            }
            last_end = token.end;
            t += 1;
        }
        loc
    }

    /// Start of the field or element with exactly this path.
    pub fn locate_exact(&self, path: &str) -> Option<Position> {
        self.entries
            .iter()
            .find(|e| e.path == path)
            .map(|e| e.start)
    }

    /// Start of the field `path`, or of its nearest ancestor present in the text (a field
    /// left at its default is reported where its parent is written), or of the top-level
    /// value. Returns the position and the path actually found (`""` for the top level).
    pub fn locate<'p>(&self, path: &'p str) -> Option<(Position, &'p str)> {
        let mut p = path;
        loop {
            if p.is_empty() {
                return self.root.map(|r| (r, ""));
            }
            if let Some(pos) = self.locate_exact(p) {
                return Some((pos, p));
            }
            p = parent_path(p);
        }
    }

    /// Path of the innermost field or element whose text contains `pos` (`None`: the
    /// position is outside every field, e.g. at the top level).
    pub fn path_at(&self, pos: Position) -> Option<&str> {
        self.entries
            .iter()
            .filter(|e| e.start <= pos && e.end.is_none_or(|end| pos <= end))
            .max_by(|a, b| a.start.cmp(&b.start))
            .map(|e| e.path.as_str())
    }
}

/// `a.b[2].c` → `a.b[2]` → `a.b` → `a` → `""`.
pub fn parent_path(path: &str) -> &str {
    match path.rfind(['.', '[']) {
        Some(i) => &path[..i],
        None => "",
    }
}

/// The position of the first bracket that opens a value nested more than `limit` levels deep,
/// if any (brackets in strings and comments do not count). Linear in the text, so it can run
/// before the parser and the [`Locator`], whose path records grow with the depth.
pub fn too_deep(text: &str, limit: usize) -> Option<Position> {
    let mut lexer = Lexer::new(text);
    let mut depth = 0usize;
    while let Some(t) = lexer.next_token() {
        match t.tok {
            Tok::Punct('(' | '[' | '{') => {
                depth += 1;
                if depth > limit {
                    return Some(t.start);
                }
            }
            Tok::Punct(')' | ']' | '}') => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = r##"#![enable(implicit_some)]
// A comment with (unbalanced [ brackets and "quotes
Scene(
    dx: 0.01, /* block /* nested */ comment ) */
    name: "tricky ( [ \" string",
    raw: r#"raw ) " string"#,
    c: ')',
    bodies: [
        (
            material: "water",
            shape: Sphere(center: (0.1, 0.2, -3e-1), radius: -0.1),
        ),
        (material: "oil", shape: Box(min: (0, 0, 0), max: (1, 1, 1))),
    ],
    time_step: (mode: Fixed(1e-4)),
)
"##;

    fn pos(line: usize, col: usize) -> Position {
        Position { line, col }
    }

    #[test]
    fn locates_fields_and_elements() {
        let l = Locator::new(TEXT);
        assert_eq!(l.locate_exact("dx"), Some(pos(4, 5)));
        assert_eq!(l.locate_exact("name"), Some(pos(5, 5)));
        assert_eq!(l.locate_exact("raw"), Some(pos(6, 5)));
        assert_eq!(l.locate_exact("c"), Some(pos(7, 5)));
        assert_eq!(l.locate_exact("bodies"), Some(pos(8, 5)));
        assert_eq!(l.locate_exact("bodies[0]"), Some(pos(9, 9)));
        assert_eq!(l.locate_exact("bodies[0].material"), Some(pos(10, 13)));
        assert_eq!(l.locate_exact("bodies[0].shape"), Some(pos(11, 13)));
        assert_eq!(
            l.locate_exact("bodies[0].shape.center[2]"),
            Some(pos(11, 46))
        );
        assert_eq!(l.locate_exact("bodies[0].shape.radius"), Some(pos(11, 54)));
        assert_eq!(l.locate_exact("bodies[1].shape.max"), Some(pos(13, 54)));
        assert_eq!(l.locate_exact("time_step.mode"), Some(pos(15, 17)));
        assert_eq!(l.locate_exact("time_step.mode[0]"), Some(pos(15, 29)));
    }

    #[test]
    fn newtype_variant_wrapping_a_struct_is_transparent() {
        let text =
            "(rheology: [(material: \"m\", model: Model((\n    a: 1.0,\n    b: (1, 2),\n)))])";
        let l = Locator::new(text);
        assert_eq!(l.locate_exact("rheology[0].model.a"), Some(pos(2, 5)));
        assert_eq!(l.locate_exact("rheology[0].model.b[1]"), Some(pos(3, 12)));
        assert_eq!(l.path_at(pos(2, 9)), Some("rheology[0].model.a"));
        // A tuple whose first element is a tuple keeps its indices.
        let l = Locator::new("(t: ((1, 2), 3))");
        assert_eq!(l.locate_exact("t[0][1]"), Some(pos(1, 10)));
        assert_eq!(l.locate_exact("t[1]"), Some(pos(1, 14)));
    }

    #[test]
    fn falls_back_to_ancestors() {
        let l = Locator::new(TEXT);
        assert_eq!(l.locate("bodies[0].jitter"), Some((pos(9, 9), "bodies[0]")));
        assert_eq!(l.locate("walls.x_min"), Some((pos(3, 1), "")));
        assert_eq!(Locator::new("").locate("dx"), None);
    }

    #[test]
    fn position_to_path() {
        let l = Locator::new(TEXT);
        assert_eq!(l.path_at(pos(11, 63)), Some("bodies[0].shape.radius"));
        assert_eq!(l.path_at(pos(11, 30)), Some("bodies[0].shape.center"));
        // On the closing `)` of Sphere(...): the shape.
        assert_eq!(l.path_at(pos(11, 66)), Some("bodies[0].shape"));
        assert_eq!(l.path_at(pos(16, 1)), None);
    }

    #[test]
    fn malformed_text_does_not_panic() {
        for text in [
            "(((",
            ")))",
            "(a: [1, 2",
            "(a: \"unterminated",
            "/* open",
            "(a: r##\"x\"#)",
            "#![",
            "(a:: b)",
        ] {
            let l = Locator::new(text);
            let _ = l.locate("a[0].b");
            let _ = l.path_at(pos(1, 3));
        }
    }
}
