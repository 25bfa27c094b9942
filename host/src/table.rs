//! The one reader of tables: CSV files with a header of column names and numeric (or text)
//! fields. Every command that reads a CSV goes through it, so every file is read by the same rules
//! and every error reads the same way.
//!
//! # Format
//! - The first line that is neither blank nor a comment is the header: comma-separated column
//!   names. Columns are looked up by name, in any order; columns nobody asks for are ignored. A
//!   name that appears twice is an error (which of the two would be meant?).
//! - UTF-8, with or without a byte-order mark (Excel's "CSV UTF-8" writes one); lines end in LF or
//!   CRLF. Blank lines and lines starting with `#` are skipped.
//! - Fields are trimmed of surrounding spaces. Numbers are finite f64 (`nan`, `inf` are refused)
//!   or integers where the column holds counts.
//!
//! # Errors
//! Every error names `file:line:column` — the 1-based line and the 1-based character column where
//! the field starts, as a compiler does — and the column's name; a long field is shortened in the
//! message. The file is read a line at a time ([`Table::next_row`]), so a table of any length is
//! read in constant memory by a caller that keeps only what it needs.
//!
//! # Limits
//! A line is at most [`MAX_LINE_BYTES`] (1 MiB); a table read a row at a time at most
//! [`Limit::Stream`] (4 GiB), one read whole at most [`Limit::Table`] (256 MiB); a whole-file
//! document ([`read_text`]: TOML, JSON) at most [`Limit::Document`] (16 MiB). Above a limit the
//! read stops with an error naming it (exit 2).
use std::collections::HashMap;
use std::io::{BufRead, BufReader, Read};
use std::ops::Range;
use std::path::{Path, PathBuf};

use crate::fsio::{Limit, MAX_LINE_BYTES};
use crate::{Error, Result};

/// The key of a record's comment line `# instrument_serial: …` (the device's serial number, as
/// `jdbb record` writes it when the device describes itself).
pub const INSTRUMENT_SERIAL: &str = "instrument_serial";
/// Longest field (in characters) quoted whole in an error message.
const SHOWN_CHARS: usize = 40;

/// A column found in the header: its index among the fields and its name.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Column {
    /// 0-based field index.
    pub index: usize,
    /// The name as the header spells it.
    pub name: String,
}

/// A table being read: the header is parsed on [`Table::open`], rows come one at a time from
/// [`Table::next_row`].
pub struct Table {
    path: PathBuf,
    reader: Box<dyn BufRead>,
    names: Vec<String>,
    /// Each name's field index (the first, for repeated empty names).
    index: HashMap<String, usize>,
    header_text: String,
    header_line: usize,
    /// Line number of the line in `line` (1-based).
    line_no: usize,
    raw: Vec<u8>,
    line: String,
    fields: Vec<Range<usize>>,
    /// 1-based character column of each field's start.
    columns: Vec<usize>,
    /// The comment lines before the first data row (above or below the header), without `#`
    /// and trimmed (see [`Table::header_comment`]).
    comments: Vec<String>,
    /// Whether a data row has been read (comments after it are not the header's).
    data_started: bool,
    /// Comment lines read after the first data row (see [`Table::data_comments`]).
    data_comments: u64,
}

impl Table {
    /// Open `path` and read its header. A file that cannot be read is bad input (exit 2) with the
    /// system's reason. At most [`Limit::Stream`] bytes are read (for tables read a row at a
    /// time); see [`Table::open_with`].
    pub fn open(path: &Path) -> Result<Table> {
        Table::open_with(path, Limit::Stream)
    }

    /// [`Table::open`] reading at most `limit` bytes: a table read whole into memory is opened
    /// with [`Limit::Table`].
    pub fn open_with(path: &Path, limit: Limit) -> Result<Table> {
        let file = crate::fsio::open_input(path, limit)?;
        Table::from_reader(path, Box::new(BufReader::with_capacity(1 << 16, file)))
    }

    /// The value of a `# key: value` comment line before the first data row (the first such
    /// line), if any: how a file says what it belongs to (a record's `plan_id`, above the header)
    /// and what made it (its `instrument_serial`, written below the header once the device has
    /// described itself). Lines below the header are seen once the first row has been read.
    pub fn header_comment(&self, key: &str) -> Option<&str> {
        self.comments.iter().find_map(|c| {
            c.strip_prefix(key)
                .and_then(|r| r.trim_start().strip_prefix(':'))
                .map(str::trim)
        })
    }

    /// A table from text in memory; `path` names it in errors.
    pub fn from_text(path: &Path, text: &str) -> Result<Table> {
        Table::from_reader(
            path,
            Box::new(std::io::Cursor::new(text.as_bytes().to_vec())),
        )
    }

    /// A table from any reader; `path` names it in errors.
    pub fn from_reader(path: &Path, reader: Box<dyn BufRead>) -> Result<Table> {
        let mut t = Table {
            path: path.to_path_buf(),
            reader,
            names: vec![],
            index: HashMap::new(),
            header_text: String::new(),
            header_line: 0,
            line_no: 0,
            raw: Vec::with_capacity(256),
            line: String::with_capacity(256),
            fields: vec![],
            columns: vec![],
            comments: vec![],
            data_started: false,
            data_comments: 0,
        };
        if !t.advance()? {
            return Err(Error::input(
                path,
                t.line_no.max(1),
                0,
                "empty file; expected a header line naming the columns",
            ));
        }
        t.header_line = t.line_no;
        t.header_text = t.line.clone();
        t.names = t
            .fields
            .iter()
            .map(|r| t.line[r.clone()].to_string())
            .collect();
        // Each name's first field, by name: linear in the header's length (a header of 200 000
        // names is refused or read at once, not compared pair by pair).
        let mut index = HashMap::with_capacity(t.names.len());
        for (k, name) in t.names.iter().enumerate() {
            if let Some(&first) = index.get(name.as_str()) {
                if name.is_empty() {
                    continue;
                }
                return Err(Error::input(
                    path,
                    t.header_line,
                    t.columns[k],
                    format!(
                        "column `{name}` appears twice (fields {} and {}); remove one",
                        first + 1,
                        k + 1
                    ),
                ));
            }
            index.insert(name.clone(), k);
        }
        t.index = index;
        Ok(t)
    }

    /// The file this table is read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The column names, in file order.
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Comment lines read so far after the first data row: `jdbb record` writes each sample it
    /// marks as suspect so (`# suspect: …`), and a reader may say how many it skipped.
    pub fn data_comments(&self) -> u64 {
        self.data_comments
    }

    /// Line number of the header.
    pub fn header_line(&self) -> usize {
        self.header_line
    }

    /// The column called `name`, if the header has it.
    pub fn optional(&self, name: &str) -> Option<Column> {
        self.index.get(name).map(|&index| Column {
            index,
            name: name.to_string(),
        })
    }

    /// The columns called `names`, in that order; an error naming the first missing one and the
    /// whole set the file must have.
    pub fn require(&self, names: &[&str]) -> Result<Vec<Column>> {
        names
            .iter()
            .map(|n| {
                self.optional(n).ok_or_else(|| {
                    Error::input(
                        &self.path,
                        self.header_line,
                        0,
                        format!(
                            "missing column `{n}`; the header is `{}` but must name {}",
                            shown(&self.header_text),
                            names.join(",")
                        ),
                    )
                })
            })
            .collect()
    }

    /// An error at the header line, column `column` (0: the whole line).
    pub fn header_error(&self, column: Option<&Column>, message: impl Into<String>) -> Error {
        let col = column.map_or(0, |c| self.columns_of_header(c.index));
        Error::input(&self.path, self.header_line, col, message)
    }

    fn columns_of_header(&self, index: usize) -> usize {
        // Character column of field `index` in the header line.
        char_column(&self.header_text, index)
    }

    /// The next data row, or None at the end of the file.
    pub fn next_row(&mut self) -> Result<Option<Row<'_>>> {
        if !self.advance()? {
            return Ok(None);
        }
        self.data_started = true;
        Ok(Some(Row {
            path: &self.path,
            line_no: self.line_no,
            line: &self.line,
            fields: &self.fields,
            columns: &self.columns,
        }))
    }

    /// Read lines until one that is not blank and not a comment; split it into fields. False at
    /// the end of the file.
    fn advance(&mut self) -> Result<bool> {
        loop {
            self.raw.clear();
            let n = (&mut self.reader)
                .take(MAX_LINE_BYTES as u64 + 1)
                .read_until(b'\n', &mut self.raw)
                .map_err(|source| Error::InputFile {
                    path: self.path.clone(),
                    source,
                })?;
            if n == 0 {
                return Ok(false);
            }
            self.line_no += 1;
            if self.raw.len() > MAX_LINE_BYTES {
                return Err(Error::input(
                    &self.path,
                    self.line_no,
                    0,
                    format!(
                        "a line longer than {} MiB, the longest line jdbb reads; is this a CSV table?",
                        MAX_LINE_BYTES >> 20
                    ),
                ));
            }
            let mut bytes: &[u8] = &self.raw;
            if self.line_no == 1 {
                bytes = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
            }
            let bytes = bytes.strip_suffix(b"\n").unwrap_or(bytes);
            let bytes = bytes.strip_suffix(b"\r").unwrap_or(bytes);
            let text = match std::str::from_utf8(bytes) {
                Ok(t) => t,
                Err(e) => {
                    let good = std::str::from_utf8(&bytes[..e.valid_up_to()]).unwrap_or("");
                    return Err(Error::input(
                        &self.path,
                        self.line_no,
                        good.chars().count() + 1,
                        format!(
                            "not UTF-8 text (byte 0x{:02x}); save the file as UTF-8 CSV",
                            bytes[e.valid_up_to()]
                        ),
                    ));
                }
            };
            let trimmed = text.trim();
            if trimmed.is_empty() || trimmed.starts_with('#') {
                if self.data_started && !trimmed.is_empty() {
                    self.data_comments += 1;
                }
                if !self.data_started && self.comments.len() < 64 {
                    self.comments
                        .push(trimmed[trimmed.len().min(1)..].trim().to_string());
                }
                continue;
            }
            self.line.clear();
            self.line.push_str(text);
            self.fields.clear();
            self.columns.clear();
            let mut start = 0;
            let mut chars = 1;
            for part in self.line.split(',') {
                let lead = part.len() - part.trim_start().len();
                let r = start + lead..start + lead + part.trim().len();
                self.columns
                    .push(chars + self.line[start..start + lead].chars().count());
                self.fields.push(r);
                chars += part.chars().count() + 1;
                start += part.len() + 1;
            }
            return Ok(true);
        }
    }
}

/// 1-based character column of field `index` of a comma-separated line.
fn char_column(line: &str, index: usize) -> usize {
    line.split(',')
        .take(index)
        .map(|f| f.chars().count() + 1)
        .sum::<usize>()
        + 1
}

/// A field as quoted in an error: whole if short, else its start and its length.
pub fn shown(raw: &str) -> String {
    let n = raw.chars().count();
    if n <= SHOWN_CHARS {
        raw.to_string()
    } else {
        let head: String = raw.chars().take(SHOWN_CHARS).collect();
        format!("{head}… ({n} characters)")
    }
}

/// One data row of a [`Table`].
pub struct Row<'a> {
    path: &'a Path,
    line_no: usize,
    line: &'a str,
    fields: &'a [Range<usize>],
    columns: &'a [usize],
}

impl Row<'_> {
    /// The row's line number (1-based).
    pub fn line(&self) -> usize {
        self.line_no
    }

    /// Number of fields on the line.
    pub fn len(&self) -> usize {
        self.fields.len()
    }

    /// Whether the line has no fields (never: blank lines are skipped).
    pub fn is_empty(&self) -> bool {
        self.fields.is_empty()
    }

    /// The character column where field `index` starts (one past the line's end if missing).
    pub fn column_of(&self, index: usize) -> usize {
        self.columns
            .get(index)
            .copied()
            .unwrap_or_else(|| self.line.chars().count() + 1)
    }

    /// An input error at this row, at column `c`'s field.
    pub fn error(&self, c: &Column, message: impl Into<String>) -> Error {
        Error::input(self.path, self.line_no, self.column_of(c.index), message)
    }

    /// The trimmed text of column `c`; an error if the line is too short.
    pub fn text(&self, c: &Column) -> Result<&str> {
        match self.fields.get(c.index) {
            Some(r) => Ok(&self.line[r.clone()]),
            None => Err(self.error(
                c,
                format!(
                    "missing value for `{}` ({} fields on this line, the header has more)",
                    c.name,
                    self.fields.len()
                ),
            )),
        }
    }

    /// The finite number in column `c`.
    pub fn number(&self, c: &Column) -> Result<f64> {
        let raw = self.text(c)?;
        match raw.parse::<f64>() {
            Ok(x) if x.is_finite() => Ok(x),
            Ok(_) => Err(self.error(
                c,
                format!("{} is {}; every value must be finite", c.name, shown(raw)),
            )),
            Err(_) if raw.is_empty() => Err(self.error(c, format!("{} is empty", c.name))),
            Err(_) => Err(self.error(c, format!("{}: `{}` is not a number", c.name, shown(raw)))),
        }
    }

    /// The integer in column `c` (encoder counts, sequence numbers).
    pub fn integer(&self, c: &Column) -> Result<i64> {
        let raw = self.text(c)?;
        raw.parse::<i64>()
            .map_err(|_| self.error(c, format!("{}: `{}` is not an integer", c.name, shown(raw))))
    }
}

/// Read a whole file into columns: for each name in `names`, the numbers of that column, with
/// each row's line number. For the small tables (parameter sets, angle-indexed runs); long
/// records are read row by row with [`Table::next_row`].
pub fn read_columns(path: &Path, names: &[&str]) -> Result<(Vec<usize>, Vec<Vec<f64>>)> {
    let mut t = Table::open_with(path, Limit::Table)?;
    let cols = t.require(names)?;
    let mut lines = vec![];
    let mut out = vec![vec![]; names.len()];
    while let Some(row) = t.next_row()? {
        for (k, c) in cols.iter().enumerate() {
            out[k].push(row.number(c)?);
        }
        lines.push(row.line());
    }
    Ok((lines, out))
}

/// Line and column (1-based, the column in characters) of byte offset `byte` in `text`: where a
/// whole-file parser (TOML) reports an error, as the CSV reader's `file:line:column`.
pub fn line_col(text: &str, byte: usize) -> (usize, usize) {
    let before = &text[..byte.min(text.len())];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
    (line, col)
}

/// Read all of `path` as text for a parser that needs the whole file (TOML, JSON), at most
/// [`Limit::Document`] bytes; bad input (exit 2) if it cannot be read, is larger, or is not UTF-8.
pub fn read_text(path: &Path) -> Result<String> {
    let bytes = crate::fsio::read_input(path, Limit::Document)?;
    match String::from_utf8(bytes) {
        Ok(mut s) => {
            if s.starts_with('\u{feff}') {
                s.drain(..3);
            }
            Ok(s)
        }
        Err(e) => {
            let b = e.as_bytes();
            let at = e.utf8_error().valid_up_to();
            let before = &b[..at];
            let line = before.iter().filter(|&&c| c == b'\n').count() + 1;
            let line_start = before
                .iter()
                .rposition(|&c| c == b'\n')
                .map_or(0, |i| i + 1);
            let col =
                std::str::from_utf8(&before[line_start..]).map_or(1, |s| s.chars().count() + 1);
            Err(Error::input(
                path,
                line,
                col,
                format!(
                    "not UTF-8 text (byte 0x{:02x}); save the file as UTF-8",
                    b[at]
                ),
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn table(text: &str) -> Result<Table> {
        Table::from_text(Path::new("t.csv"), text)
    }

    #[test]
    fn columns_by_name_in_any_order_extra_ignored() {
        let mut t = table("# comment\n\nb, a ,extra\n2,1,x\n\n4 ,3,y\n").unwrap();
        let c = t.require(&["a", "b"]).unwrap();
        assert_eq!(t.header_line(), 3);
        let mut got = vec![];
        while let Some(r) = t.next_row().unwrap() {
            got.push((r.line(), r.number(&c[0]).unwrap(), r.number(&c[1]).unwrap()));
        }
        assert_eq!(got, vec![(4, 1.0, 2.0), (6, 3.0, 4.0)]);
    }

    #[test]
    fn bom_and_crlf_are_accepted() {
        let mut t = table("\u{feff}t_s,d_mm\r\n0,90.5\r\n1,90.25\r\n").unwrap();
        let c = t.require(&["t_s", "d_mm"]).unwrap();
        let r = t.next_row().unwrap().unwrap();
        assert_eq!(r.number(&c[1]).unwrap(), 90.5);
        let r = t.next_row().unwrap().unwrap();
        assert_eq!((r.line(), r.number(&c[0]).unwrap()), (3, 1.0));
        assert!(t.next_row().unwrap().is_none());
    }

    #[test]
    fn errors_name_file_line_character_column_and_column_name() {
        let mut t = table("a,b\n1, nan\n").unwrap();
        let c = t.require(&["a", "b"]).unwrap();
        let e = t.next_row().unwrap().unwrap().number(&c[1]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "t.csv:2:4: b is nan; every value must be finite"
        );
        let mut t = table("a,b\n1,x2\n").unwrap();
        let c = t.require(&["a", "b"]).unwrap();
        let e = t.next_row().unwrap().unwrap().number(&c[1]).unwrap_err();
        assert_eq!(e.to_string(), "t.csv:2:3: b: `x2` is not a number");
        let mut t = table("a,b\n1\n").unwrap();
        let c = t.require(&["a", "b"]).unwrap();
        let e = t.next_row().unwrap().unwrap().number(&c[1]).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("t.csv:2:2: missing value for `b`"),
            "{e}"
        );
        let e = table("a,b\n").unwrap().require(&["a", "d_mm"]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "t.csv:1: missing column `d_mm`; the header is `a,b` but must name a,d_mm"
        );
        assert_eq!(e.exit_code(), 2);
    }

    #[test]
    fn a_duplicate_column_is_refused() {
        let e = table("t_s,d_mm,x,d_mm\n").err().unwrap();
        assert_eq!(
            e.to_string(),
            "t.csv:1:12: column `d_mm` appears twice (fields 2 and 4); remove one"
        );
    }

    #[test]
    fn a_long_bad_field_is_shortened() {
        let long = "z".repeat(500_000);
        let mut t = table(&format!("a\n{long}\n")).unwrap();
        let c = t.require(&["a"]).unwrap();
        let e = t.next_row().unwrap().unwrap().number(&c[0]).unwrap_err();
        let msg = e.to_string();
        assert!(msg.len() < 200, "{} bytes", msg.len());
        assert!(msg.contains("(500000 characters)"), "{msg}");
    }

    #[test]
    fn a_line_without_end_stops_at_the_limit() {
        // `/dev/zero` as a table: one endless line, refused at the line limit, not read whole.
        let e = Table::open(Path::new("/dev/zero")).err().unwrap();
        assert_eq!(e.exit_code(), 2);
        assert!(
            e.to_string()
                .starts_with("/dev/zero:1: a line longer than 1 MiB"),
            "{e}"
        );
    }

    #[test]
    fn non_utf8_names_line_and_column() {
        let bytes = b"a,b\n1,2\n3,\xff4\n".to_vec();
        let mut t =
            Table::from_reader(Path::new("t.csv"), Box::new(std::io::Cursor::new(bytes))).unwrap();
        t.next_row().unwrap();
        let e = t.next_row().err().unwrap();
        assert_eq!(
            e.to_string(),
            "t.csv:3:3: not UTF-8 text (byte 0xff); save the file as UTF-8 CSV"
        );
        assert_eq!(e.exit_code(), 2);
    }

    #[test]
    fn empty_file_and_missing_file() {
        let e = table("\n\n# nothing\n").err().unwrap();
        assert!(e.to_string().starts_with("t.csv:3: empty file"), "{e}");
        let e = Table::open(Path::new("/nonexistent/nope.csv"))
            .err()
            .unwrap();
        assert_eq!(e.exit_code(), 2);
        assert!(e.to_string().contains("nope.csv"), "{e}");
    }

    #[test]
    fn integers() {
        let mut t = table("enc1\n-8388608\n1.5\n").unwrap();
        let c = t.require(&["enc1"]).unwrap();
        assert_eq!(
            t.next_row().unwrap().unwrap().integer(&c[0]).unwrap(),
            -8388608
        );
        let e = t.next_row().unwrap().unwrap().integer(&c[0]).unwrap_err();
        assert_eq!(e.to_string(), "t.csv:3:1: enc1: `1.5` is not an integer");
    }
}
