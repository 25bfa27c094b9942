//! A recording (time and D, with its lines and glitches) read and checked.
use super::*;

/// A recording: time (s after its first sample) and D (mm).
#[derive(Debug, Clone)]
pub struct Record {
    pub path: PathBuf,
    /// The first sample's `t_us` (the origin of `t_s`).
    pub t0_us: f64,
    pub t_s: Vec<f64>,
    pub d_mm: Vec<f64>,
    /// The plan the record was made for (its `# plan_id:` line), if it says.
    pub plan_id: Option<String>,
    /// Line number of each sample in the file (errors name it).
    pub(super) lines: Vec<u32>,
    /// The samples set aside as glitches ([`crate::sync::glitch`]): not in `t_s` and `d_mm`.
    pub glitches: Vec<Glitch>,
    /// Samples the recorder marked as suspect (`# suspect:` comment lines among the data),
    /// skipped as every comment line.
    pub marked: u64,
}

impl Record {
    /// The file line of sample `i` (for messages).
    pub fn line_of(&self, i: usize) -> usize {
        self.lines.get(i).map_or(0, |&l| l as usize)
    }

    /// Read a `jdbb record` file (`seq,t_us,enc1,enc2,d_mm`; only `t_us` and `d_mm` are used,
    /// extra columns ignored). Time must increase strictly (a record holds one run), D be
    /// positive, and the samples at most [`MAX_RECORD_SAMPLES`]; glitches are set aside
    /// ([`Record::glitches`]).
    pub fn read(path: &FsPath) -> Result<Record> {
        Record::read_at_most(path, MAX_RECORD_SAMPLES)
    }

    /// [`Record::read`] with at most `max` samples.
    pub(super) fn read_at_most(path: &FsPath, max: usize) -> Result<Record> {
        let mut t = Table::open(path)?;
        let cols = t.require(&["t_us", "d_mm"])?;
        let mut rec = Record {
            path: path.to_path_buf(),
            t0_us: 0.0,
            t_s: vec![],
            d_mm: vec![],
            plan_id: t
                .header_comment(crate::plan::PLAN_ID_KEY)
                .map(str::to_string),
            lines: vec![],
            glitches: vec![],
            marked: 0,
        };
        let mut prev: Option<f64> = None;
        while let Some(row) = t.next_row()? {
            if rec.t_s.len() >= max {
                return Err(row.error(
                    &cols[0],
                    format!(
                        "more than {max} samples (33 min at 5 kHz, 2.8 h at 1 kHz), the most a record is read with (in bounded memory, about 1 GB): a ballbar test lasts minutes. Record the test alone (`jdbb record --plan` stops at the program's end), or at a lower --rate"
                    ),
                ));
            }
            let t_us = row.number(&cols[0])?;
            let d = row.number(&cols[1])?;
            if let Some(p) = prev {
                if t_us <= p {
                    return Err(row.error(
                        &cols[0],
                        format!("time goes backwards or stands still ({t_us} µs after {p} µs); a record holds one run"),
                    ));
                }
            } else {
                rec.t0_us = t_us;
            }
            if d <= 0.0 {
                return Err(row.error(
                    &cols[1],
                    format!("d_mm is {d}; a ball distance is positive"),
                ));
            }
            prev = Some(t_us);
            rec.t_s.push((t_us - rec.t0_us) * 1e-6);
            rec.d_mm.push(d);
            rec.lines.push(row.line().min(u32::MAX as usize) as u32);
        }
        rec.marked = t.data_comments();
        let read = rec.t_s.len();
        rec.set_glitches_aside();
        if rec.glitches.len() > read / MAX_GLITCH_SHARE {
            return Err(Error::input(
                path,
                rec.glitches[0].line,
                0,
                format!(
                    "{} of {read} samples lie far off the samples around them (glitches; the first here): more than one in {MAX_GLITCH_SHARE} is not a glitch but a faulty instrument or cable. Check the cable and the instrument, then record the test again",
                    rec.glitches.len()
                ),
            ));
        }
        if rec.t_s.len() < 10 {
            return Err(Error::input(
                path,
                t.header_line(),
                0,
                format!("only {} samples: not a recording of a test", rec.t_s.len()),
            ));
        }
        Ok(rec)
    }

    /// Take the glitches ([`crate::sync::glitch::find`]) out of `t_s`, `d_mm` and `lines` into
    /// `glitches`.
    pub(super) fn set_glitches_aside(&mut self) {
        let found = crate::sync::glitch::find(&self.d_mm);
        if found.is_empty() {
            return;
        }
        let mut next = found.iter().peekable();
        let mut keep = 0;
        for i in 0..self.t_s.len() {
            if next.peek() == Some(&&i) {
                next.next();
                self.glitches.push(Glitch {
                    line: self.line_of(i),
                    t_s: self.t_s[i],
                    d_mm: self.d_mm[i],
                });
                continue;
            }
            self.t_s[keep] = self.t_s[i];
            self.d_mm[keep] = self.d_mm[i];
            self.lines[keep] = self.lines[i];
            keep += 1;
        }
        self.t_s.truncate(keep);
        self.d_mm.truncate(keep);
        self.lines.truncate(keep);
    }

    /// Whether line `line` of the file is a sample the record holds (not set aside, not a
    /// comment).
    pub fn holds_line(&self, line: usize) -> bool {
        self.lines
            .binary_search(&(line.min(u32::MAX as usize) as u32))
            .is_ok()
    }

    /// What was set aside (glitches, samples the recorder marked) and where, in words; None if
    /// nothing was. `sync` places the glitches in its circles.
    pub fn set_aside_note(&self, sync: Option<&Sync>) -> Option<String> {
        let circle_of = |t: f64| {
            sync?
                .circles
                .iter()
                .position(|c| t >= c.feed_in.profile.t0_s && t <= c.feed_out.profile.end_s())
        };
        let glitches = crate::sync::glitch::describe(&self.glitches, &circle_of);
        let marked = (self.marked > 0).then(|| {
            format!(
                "{} sample{} the recorder marked as suspect (`# suspect:` lines) left out",
                self.marked,
                if self.marked == 1 { "" } else { "s" }
            )
        });
        match (glitches, marked) {
            (None, None) => None,
            (Some(g), None) => Some(g),
            (None, Some(m)) => Some(m),
            (Some(g), Some(m)) => Some(format!("{g}; {m}")),
        }
    }

    /// A record from times (s) and distances (mm) in memory; `path` names it in errors.
    pub fn from_samples(path: &FsPath, t_s: Vec<f64>, d_mm: Vec<f64>) -> Record {
        let lines = (0..t_s.len()).map(|i| (i + 2) as u32).collect();
        let mut rec = Record {
            path: path.to_path_buf(),
            t0_us: 0.0,
            t_s,
            d_mm,
            plan_id: None,
            lines,
            glitches: vec![],
            marked: 0,
        };
        rec.set_glitches_aside();
        rec
    }

    pub(super) fn len(&self) -> usize {
        self.t_s.len()
    }

    /// Index of the first sample at or after `t`.
    pub(super) fn index_at(&self, t: f64) -> usize {
        self.t_s.partition_point(|&x| x < t)
    }

    /// Median of D over samples with time in [a, b] (None if there are none).
    pub(super) fn median(&self, a: f64, b: f64) -> Option<f64> {
        let (i, j) = (self.index_at(a), self.index_at(b.next_up()));
        if j <= i {
            return None;
        }
        let mut v: Vec<f64> = self.d_mm[i..j].to_vec();
        let mid = v.len() / 2;
        let (_, m, _) = v.select_nth_unstable_by(mid, f64::total_cmp);
        Some(*m)
    }

    /// `file:line` of sample i, for errors.
    pub(super) fn location(&self, i: usize) -> String {
        format!(
            "{}:{}",
            self.path.display(),
            self.lines.get(i).copied().unwrap_or(0)
        )
    }
}
