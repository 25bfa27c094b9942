//! The parser's half of reading a program: G-code text → one [`RawBlock`] of words per line, via a
//! `gcode::core` visitor that keeps what the crate's AST drops (O numbers, the source text of every
//! number). The meaning of the words is [`super::program`]'s business.
//!
//! Numbers: `gcode` hands out `f32` literals (≈ 7 significant digits: 1 ulp is 1.5e-5 mm at
//! 238 mm, 3e-5 mm at 500 mm — a few hundredths of a µm, but enough to put arc end points off
//! their circle and to bias every coordinate by up to half an ulp). So each number is read again,
//! as `f64`, from the source text the parser's span points at, and checked against the `f32` value.
//! A coordinate printed with 4 decimals is then exact to its last digit (0.1 µm), the program's
//! own resolution.

use gcode::core::{
    BlockVisitor, CommandVisitor, ControlFlow, Diagnostics, Number, ProgramVisitor, Span,
    TokenType, Value,
};

use super::program::ProgramError;

/// One address word, e.g. `X-12.5`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Word {
    /// Upper-case letter.
    pub letter: char,
    /// Value, read as f64 from the source text.
    pub value: f64,
    /// Written with a decimal point (Fanuc reads integers in least increments).
    pub point: bool,
}

/// Everything written on one line.
#[derive(Debug, Default)]
pub(super) struct RawBlock {
    /// Source line, 1-based.
    pub line: usize,
    /// `N` number.
    pub n: Option<u32>,
    /// `O` program number.
    pub o: Option<u32>,
    /// G codes as (major, minor): `G91.1` = (91, 1).
    pub g: Vec<(u32, u32)>,
    /// M codes.
    pub m: Vec<(u32, u32)>,
    /// A T word was written.
    pub t: bool,
    /// Address words (arguments of the codes and bare words alike: all belong to the line).
    pub words: Vec<Word>,
}

/// Split `text` into lines of words; the first syntax problem is an error naming its line.
pub(super) fn read_blocks(text: &str) -> Result<Vec<RawBlock>, ProgramError> {
    let mut c = Collector {
        src: text,
        lines: text.lines().collect(),
        blocks: Vec::new(),
        problem: None,
    };
    gcode::core::parse(text, &mut c);
    match c.problem {
        Some(p) => Err(p),
        None => Ok(c.blocks),
    }
}

struct Collector<'s> {
    src: &'s str,
    lines: Vec<&'s str>,
    blocks: Vec<RawBlock>,
    problem: Option<ProgramError>,
}

impl Collector<'_> {
    fn note(&mut self, span: Span, message: String) {
        if self.problem.is_none() {
            self.problem = Some(ProgramError {
                line: span.line + 1,
                message,
            });
        }
    }

    fn word(&mut self, letter: char, value: Value<'_>, span: Span) -> Option<Word> {
        let letter = letter.to_ascii_uppercase();
        let lit = match value {
            Value::Literal(v) => v,
            Value::Variable(v) => {
                self.note(
                    span,
                    format!("{letter}#{v}: parameters are not supported; write the number"),
                );
                return None;
            }
        };
        let text = self
            .src
            .get(span.start..span.start + span.length)
            .unwrap_or("");
        let digits = text.get(1..).unwrap_or("").trim();
        match digits.parse::<f64>() {
            Ok(v) if v.is_finite() && (v - lit as f64).abs() <= 1e-6 * (1.0 + v.abs()) => {
                Some(Word {
                    letter,
                    value: v,
                    point: digits.contains('.'),
                })
            }
            _ => {
                self.note(span, format!("cannot read the number in {text:?}"));
                None
            }
        }
    }
}

impl Diagnostics for Collector<'_> {
    fn emit_unknown_content(&mut self, text: &str, span: Span) {
        self.note(span, format!("cannot read {text:?}"));
    }
    fn emit_unexpected(&mut self, actual: &str, expected: &[TokenType], span: Span) {
        let exp: Vec<&str> = expected.iter().map(|t| t.as_str()).collect();
        self.note(
            span,
            format!("unexpected {actual:?} (expected {})", exp.join(" or ")),
        );
    }
    fn emit_parse_int_error(&mut self, value: &str, error: std::num::ParseIntError, span: Span) {
        self.note(span, format!("bad N/O number {value:?}: {error}"));
    }
}

struct LineVisitor<'a, 's> {
    c: &'a mut Collector<'s>,
    b: RawBlock,
}

impl Diagnostics for LineVisitor<'_, '_> {
    fn emit_unknown_content(&mut self, text: &str, span: Span) {
        self.c.emit_unknown_content(text, span)
    }
    fn emit_unexpected(&mut self, actual: &str, expected: &[TokenType], span: Span) {
        self.c.emit_unexpected(actual, expected, span)
    }
    fn emit_parse_int_error(&mut self, value: &str, error: std::num::ParseIntError, span: Span) {
        self.c.emit_parse_int_error(value, error, span)
    }
}

struct CodeVisitor<'a, 'b, 's> {
    line: &'a mut LineVisitor<'b, 's>,
}

impl Diagnostics for CodeVisitor<'_, '_, '_> {
    fn emit_unknown_content(&mut self, text: &str, span: Span) {
        self.line.emit_unknown_content(text, span)
    }
    fn emit_unexpected(&mut self, actual: &str, expected: &[TokenType], span: Span) {
        self.line.emit_unexpected(actual, expected, span)
    }
    fn emit_parse_int_error(&mut self, value: &str, error: std::num::ParseIntError, span: Span) {
        self.line.emit_parse_int_error(value, error, span)
    }
}

impl CommandVisitor for CodeVisitor<'_, '_, '_> {
    fn argument(&mut self, letter: char, value: Value<'_>, span: Span) {
        self.line.b.line = span.line + 1;
        if let Some(w) = self.line.c.word(letter, value, span) {
            self.line.b.words.push(w);
        }
    }
}

fn code(n: Number) -> (u32, u32) {
    (n.major(), n.minor().map_or(0, |m| m.get()))
}

impl BlockVisitor for LineVisitor<'_, '_> {
    fn line_number(&mut self, n: u32, span: Span) {
        self.b.line = span.line + 1;
        self.b.n = Some(n);
    }
    fn program_number(&mut self, number: u32, span: Span) {
        self.b.line = span.line + 1;
        self.b.o = Some(number);
    }
    fn comment(&mut self, _value: &str, span: Span) {
        self.b.line = span.line + 1;
    }
    fn program_delimiter(&mut self, span: Span) {
        self.b.line = span.line + 1;
    }
    fn word_address(&mut self, letter: char, value: Value<'_>, span: Span) {
        self.b.line = span.line + 1;
        if let Some(w) = self.c.word(letter, value, span) {
            self.b.words.push(w);
        }
    }
    fn start_general_code(&mut self, number: Number) -> ControlFlow<impl CommandVisitor + '_> {
        self.b.g.push(code(number));
        ControlFlow::Continue(CodeVisitor { line: self })
    }
    fn start_miscellaneous_code(
        &mut self,
        number: Number,
    ) -> ControlFlow<impl CommandVisitor + '_> {
        self.b.m.push(code(number));
        ControlFlow::Continue(CodeVisitor { line: self })
    }
    fn start_tool_change_code(&mut self, _number: Number) -> ControlFlow<impl CommandVisitor + '_> {
        self.b.t = true;
        ControlFlow::Continue(CodeVisitor { line: self })
    }
    fn end_line(mut self, span: Span) {
        self.b.line = span.line + 1;
        // A G/M code whose number does not parse (e.g. `G1.23`) is dropped by the parser with a
        // diagnostic we cannot receive (its error type is private): count the codes instead.
        let text = self.c.lines.get(span.line).copied().unwrap_or("");
        if code_letters(text) != self.b.g.len() + self.b.m.len() + usize::from(self.b.t) {
            self.c.note(
                span,
                format!("cannot read a G/M/T code in {:?}", text.trim()),
            );
        }
        self.c.blocks.push(self.b);
    }
}

/// Number of G, M and T letters in a line outside comments.
fn code_letters(line: &str) -> usize {
    let mut n = 0;
    let mut depth = 0;
    for c in line.chars() {
        match c {
            ';' if depth == 0 => break,
            '(' => depth += 1,
            ')' => depth = (depth - 1).max(0),
            'G' | 'g' | 'M' | 'm' | 'T' | 't' if depth == 0 => n += 1,
            _ => {}
        }
    }
    n
}

impl ProgramVisitor for Collector<'_> {
    fn start_block(&mut self) -> ControlFlow<impl BlockVisitor + '_> {
        ControlFlow::Continue(LineVisitor {
            c: self,
            b: RawBlock::default(),
        })
    }
}
