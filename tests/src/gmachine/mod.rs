//! An independent simulator of a CNC machine running a ballbar G-code program while a J-DBB
//! records it: the test harness the host's synchronisation and diagnosis are checked against.
//!
//! Input: the G-code program text and this module's own machine, error and instrument
//! configuration — nothing from the host's circular-test code, `jdbb plan` or plan.json, so that
//! a wrong convention there cannot cancel against the same convention here. Output: the rows
//! `jdbb record` writes (`seq,t_us,enc1,enc2,d_mm`) and the [`Truth`] behind them.
//!
//! ```text
//!  G-code ──program──▶ blocks ──planner──▶ p(t) ──errors──▶ spindle & table ball ──▶ D(t)
//!          (dialect)           (lookahead,       (δ per axis,                        │
//!                               trapezoids)       set-up, drift)                     ▼
//!   rows ◀── device D (core kernel) ◀── counts (mechanism model, wandering lean ψ) ◀── D + noise
//!    ▲
//!    └── device clock: t_us = t0 + round(t·(1 + ppm·1e-6)·1e6), nominal rate on that clock
//! ```
//!
//! Modules: [`program`] (G-code → blocks), [`planner`] (blocks → timed trajectory),
//! [`errors`] (machine errors), [`recorder`] (instrument, clock, CSV, truth).
//!
//! # Conventions (the contract)
//!
//! Units: positions mm in program coordinates (the coordinates the program is written in); errors
//! µm; times s (true time) unless named `_us` (device clock) or `_ms`.
//!
//! **Program.** Dialects and what differs between them:
//!
//! | | linuxcnc | grbl | fanuc | marlin |
//! |---|---|---|---|---|
//! | `G4` dwell | `P` s | `P` s | `X` s (`X` without a decimal point: ms), or `P` ms (integer) | `P` ms or `S` s |
//! | `O` words | refused | refused | program number, ignored | refused |
//! | length without a decimal point | mm | mm | 0.001 mm (factory "decimal point input"; [`FanucInput::Calculator`] for mm) | mm |
//!
//! All dialects: `G0` (at [`MachineConfig::rapid_mm_min`]; note stock Marlin runs G0 at the
//! feed — not modelled), `G1`, `G2`/`G3` with incremental `I`/`J`/`K` or `R` (R < 0: the arc over
//! 180°; start = end with I/J/K: a full circle), planes `G17` (x, y; normal +z), `G18` (z, x;
//! normal +y), `G19` (y, z; normal +x) — arcs seen from the positive end of the normal: `G2`
//! clockwise, `G3` counter-clockwise, i.e. angular velocity along −n / +n; helical arcs (end point
//! off the plane). `G21` (`G20` refused: inches), `G90`/`G91`, `G91.1` (`G90.1` refused), `G94`
//! (`G93`/`G95` refused), `F` mm/min modal, `G61` (exact stop: stop after each move) / `G64` (its
//! `P`/`Q` tolerance is accepted and not needed: only tangent junctions are blended), `G40`,
//! `G49`, `G54` accepted as no-ops (nothing to cancel, the program coordinates are the work
//! coordinates), `G80` (motion mode off). `M0` / `M1` (program stop, M1 only with
//! [`MachineConfig::optional_stop`]), `M2`/`M30` (program end; later lines are not run; a program
//! may also just end), `M3`/`M4`/`M5` and `S` ignored (the instrument sits in the spindle).
//! Comments `( )` and `;`, `N` line numbers, `%` lines. Anything else — other G/M codes, `T`,
//! parameters (`#1`), expressions, unknown letters, a word twice in a line, an arc whose end is off
//! its circle by more than [`ARC_RADIUS_TOLERANCE_MM`], a feed move before any `F` — is an error
//! naming the line ([`ProgramError`]).
//!
//! Numbers: the `gcode` crate gives `f32` values (7 digits: up to 3e-5 mm off at 500 mm); we read
//! each number again as `f64` from the source text at the parser's span, so coordinates are exact
//! to their printed digits and the f32 rounding has no consequence here.
//!
//! **Motion.** See [`planner`]: per-axis acceleration limits, trapezoidal profile along the path,
//! tangent junctions (within [`MachineConfig::blend_angle_deg`]) blended, stops at corners,
//! reversals, dwells and program stops, arcs slowed so v²/R ≤ (√3/2)·min(a_plane axes), lookahead
//! over the whole program. The feed override scales G1/G2/G3 feeds, not rapids.
//!
//! **Time line.** Program time 0 is when the first block starts, with the machine at
//! [`MachineConfig::initial_position_mm`]. The first honoured program stop (`M0`, or `M1` with the
//! switch on) is where the operator mounts the instrument: the recording starts when the machine
//! arrives there and cycle start (the press that ends the stop) follows
//! [`InstrumentConfig::start_delay_s`] later. Without a program stop, cycle start is program time 0
//! and the recording starts `start_delay_s` before it, the machine standing at its initial
//! position. Later stops last [`MachineConfig::stop_wait_s`]. The recording ends
//! [`InstrumentConfig::tail_s`] after the program's last block.
//!
//! **Machine errors** ([`MachineErrors`]), each a displacement δ (µm) of the spindle ball added to
//! the commanded position p(t), per axis k:
//! - *set-up offset* c (µm per axis): the table ball is at `table_ball_mm` + c (`table_ball_mm` is
//!   where the program's test centre is, i.e. where the operator was told to put the ball);
//!   D = |spindle ball − table ball|. *Length offset* e (µm) is added to D.
//! - *backlash* b_k (µm): a clearance between the motor (which follows the command) and the
//!   carriage, i.e. play. Written as the mechanism, not as a formula: the carriage is pushed by
//!   one flank of the nut, so it sits b/2 behind the motor in the direction of motion; when the
//!   motor reverses it leaves the carriage where it was until it has crossed the clearance and
//!   meets the other flank (a play operator: carriage = clamp(carriage, motor − b/2, motor + b/2)
//!   applied over each monotonic stretch of the motor). Before the first move the clearance is
//!   closed per [`MachineConfig::initial_direction`]. A negative b (over-compensation: the
//!   controller jumps the motor through more than the clearance) is a step: the carriage runs
//!   |b|/2 ahead. [`BacklashEnds`] makes the clearance a linear function of the axis position
//!   (a screw worn more at one end). On a circle the step part gives ΔD ≈ ∓(b/2)·cos θ.
//! - *bow* ([`Bow`]): axis i is not straight: moving along it displaces axis j by
//!   κ·(p_i − vertex_i)² (κ in µm/m², the vertex in program coordinates).
//! - *lateral play* ([`LateralPlay`]): the carriage of axis i shifts across its guideway
//!   clearance by ±l/2 in j with the direction of i (+ while i moves in +).
//! - *scale* a_k (µm/m): δ_k = a_k·p_k, p_k measured from the **program origin** (not from the
//!   table ball: the two differ by a constant displacement a_k·ball_k, which only shifts the
//!   circle's centre).
//! - *squareness* s (µm/m) of axis i by axis j: δ_i = s·(p_j − ball_j), j's coordinate relative
//!   to the (nominal) table ball. On a circle in xy with δ_x = s·y: ΔD ≈ δ·u = s·x·y/R.
//! - *cyclic* (A µm, pitch P mm, phase φ): δ_k = A·sin(2π·p_k/P + φ), p_k from the program origin.
//! - *second-order scale* ([`Scale2`]: b µm/m², origin o mm): a lead that changes linearly along
//!   the screw, δ_k = b·(p_k − o)², + on both sides of o for b > 0.
//! - *interference* ([`Interference`]: τ_c ms, signal period P mm, phase φ): the read head reports
//!   the position late by τ(p) = τ_c·sin(2π·p_k/P + φ) and the servo holds the reading on the
//!   command, so the axis is at its command τ(p) *later*: actual_k(t) = command_k(t + τ(p)),
//!   δ_k ≈ +v_k·τ(p) (τ_c in ms is the amplitude in µm per mm/s). Evaluated as a time shift,
//!   after the servo delay.
//! - *servo delay* τ_k (ms): a true delay, actual_k(t) = command_k(t − τ_k) (not −τ·v); the
//!   axis' own errors above are evaluated at its delayed position and direction state, and a
//!   squareness term uses the delayed position of the axis j that causes it.
//! - *reversal spike* (h µm, τ ms): at each reversal of axis k at t_rev (a change of the axis'
//!   direction of motion), δ_k = −h·s_new·exp(−(t − t_rev)/τ) for t ≥ t_rev, s_new = ±1 the new
//!   direction — the axis sticks, then catches up; the next reversal replaces the spike. A first
//!   move in the same direction as `initial_direction` is no reversal.
//! - *drift* (µm/min): D += drift·(t − t_cycle_start) for t ≥ cycle start, 0 before (warm-up).
//! - *dynamics* ([`dynamics`]): per-axis position loops (Kv, velocity-loop bandwidth, velocity
//!   and acceleration feed-forward, the axis held on its encoder counts) integrated in time on
//!   the command p(t); their following error moves the carriage, and the axis's own errors above
//!   are evaluated where the carriage is. Coulomb + Stribeck friction inside the loop (stick-slip
//!   at reversals, per end), structural modes driven by the drive force, an axis's scale growing
//!   in time about its fixed bearing, the spindle growing towards the table.
//!
//! **Instrument.** D (true + Gaussian noise of σ = [`InstrumentConfig::noise_um`] on D itself,
//! and the coloured noise of [`InstrumentConfig::coloured_noise`], before quantisation) → deflection φ → frame angles for the lean azimuth ψ(t) → whole counts,
//! by the tests' own model of the instrument as built ([`crate::mechanism`]: frames as rigid
//! bodies, bar 2 found where both grip points lie in the slot planes, encoders by eq. (G9)), for
//! `true_calibration` if set, else the calibration in force — not by the core's inverse
//! `counts_for_distance`, so a convention of the core model cannot cancel here. ψ is a random
//! walk reflected within a band ([`AzimuthWalk`]); a D whose frames would leave ±75° at that ψ (or
//! beyond L1 + L2) is an error ([`SimError::OutOfReach`]) naming the time and line. The device's
//! D is the production kernel (`jdbb_core::geometry::Kernel`, what the firmware's sampler runs) on
//! those counts, so the quantisation and the chip's f32 arithmetic are real.
//!
//! **Clock.** The device samples at [`InstrumentConfig::sample_rate_hz`] *on its own clock*,
//! which runs at (1 + ppm·1e-6) × true time: sample k is taken at true time
//! t_k = k / (rate·(1 + ppm·1e-6)) after the recording starts and stamped
//! t_us = t0 + round(t_k·(1 + ppm·1e-6)·1e6) = t0 + round(k·1e6/rate). Seq counts from 0.
//!
//! **Truth.** Cycle start on the device clock, the feed factor, the clock error, every block's start
//! and end on both clocks, and per sample: true time, command and actual positions, true D, the
//! instrument's (noisy) D, ψ and the counts — the last four are what a QEMU scenario needs.
//!
//! Performance: each sample is evaluated analytically (binary search of the segment, closed-form
//! profile), O(log blocks); a 10-minute program at 1 kHz runs in well under a second in release.

pub mod dynamics;
pub mod errors;
pub mod planner;
pub mod program;
pub mod realistic;
pub mod recorder;
mod words;

pub use dynamics::{
    ColouredNoise, Dynamics, Friction, ServoLoop, SpindleGrowth, StructuralMode, ThermalGrowth,
};
pub use errors::{
    Axis, BacklashEnds, Bow, Cyclic, Interference, LateralPlay, MachineErrors, ReversalSpike,
    Scale2, Squareness,
};
pub use planner::{plan, MachineConfig, SegmentKind, Trajectory};
pub use program::{
    parse_program, Dialect, FanucInput, Program, ProgramError, ProgramOptions,
    ARC_RADIUS_TOLERANCE_MM,
};
pub use realistic::{Realistic, Tuning};
pub use recorder::{
    write_csv, AzimuthWalk, BlockTiming, InstrumentConfig, Recording, Row, Sample, Samples, Truth,
    TruthSample, CSV_HEADER,
};

/// Everything a simulation needs besides the program text.
#[derive(Debug, Clone, PartialEq)]
pub struct SimConfig {
    /// How to read the program.
    pub program: ProgramOptions,
    /// Where the table ball is meant to be: the program's test centre (mm, program coordinates).
    pub table_ball_mm: [f64; 3],
    /// How the machine moves.
    pub machine: MachineConfig,
    /// Its errors.
    pub errors: MachineErrors,
    /// The J-DBB and the recording.
    pub instrument: InstrumentConfig,
}

impl SimConfig {
    /// A perfect machine with default limits, the default instrument, for a program in `dialect`
    /// whose test centre (table ball) is `table_ball_mm`.
    pub fn new(dialect: Dialect, table_ball_mm: [f64; 3]) -> Self {
        SimConfig {
            program: ProgramOptions::new(dialect),
            table_ball_mm,
            machine: MachineConfig::default(),
            errors: MachineErrors::default(),
            instrument: InstrumentConfig::default(),
        }
    }
}

/// Why a simulation could not run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SimError {
    /// The program cannot be run.
    #[error("G-code {0}")]
    Program(#[from] ProgramError),
    /// A configuration value is unusable.
    #[error("simulator configuration: {0}")]
    Config(String),
    /// Writing the output failed.
    #[error("cannot write: {0}")]
    Write(String),
    /// The instrument cannot reach the distance.
    #[error(
        "{t_s:.3} s into the recording{}, D = {d_mm:.4} mm is out of the J-DBB's reach at lean \
         azimuth {azimuth_rad:.2} rad (frames beyond ±75°, or D > L1 + L2): keep every move of the \
         program within the instrument's range, or move the table ball",
        line.map(|l| format!(" (line {l})")).unwrap_or_default()
    )]
    OutOfReach {
        /// True time since the recording started (s).
        t_s: f64,
        /// Program line running then.
        line: Option<usize>,
        /// The distance asked for (mm).
        d_mm: f64,
        /// The lean azimuth (rad).
        azimuth_rad: f64,
    },
}

/// A program planned on a machine, ready to be recorded.
#[derive(Debug, Clone)]
pub struct Simulation {
    config: SimConfig,
    program: Program,
    trajectory: Trajectory,
    /// Program time of the first sample (s).
    recording_start_s: f64,
    n_samples: u64,
}

impl Simulation {
    /// Read `gcode` and plan it; the samples are computed later ([`Self::samples`], [`Self::run`]).
    pub fn new(gcode: &str, config: SimConfig) -> Result<Self, SimError> {
        config.errors.validate().map_err(SimError::Config)?;
        config.instrument.validate().map_err(SimError::Config)?;
        if !config.table_ball_mm.iter().all(|v| v.is_finite()) {
            return Err(SimError::Config("table_ball_mm must be finite".into()));
        }
        let program = parse_program(gcode, config.program, config.machine.initial_position_mm)?;
        let ins = &config.instrument;
        let trajectory = plan(&program, &config.machine, ins.start_delay_s)?;
        let recording_start_s = trajectory.cycle_start_s - ins.start_delay_s;
        let span_s = trajectory.end_s + ins.tail_s - recording_start_s;
        let n = (span_s * (1.0 + ins.clock_ppm * 1e-6) * ins.sample_rate_hz).floor() as u64 + 1;
        Ok(Simulation {
            config,
            program,
            trajectory,
            recording_start_s,
            n_samples: n,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// The program as read.
    pub fn program(&self) -> &Program {
        &self.program
    }

    /// The planned trajectory (program time).
    pub fn trajectory(&self) -> &Trajectory {
        &self.trajectory
    }

    /// Number of samples the recording will have.
    pub fn len(&self) -> usize {
        self.n_samples as usize
    }

    /// Whether the recording is empty (never: it holds at least one sample).
    pub fn is_empty(&self) -> bool {
        self.n_samples == 0
    }

    /// Program time of the first sample (s).
    pub fn recording_start_s(&self) -> f64 {
        self.recording_start_s
    }

    /// Device-clock time (µs, unrounded) of program time `t_program_s`.
    pub fn device_us(&self, t_program_s: f64) -> f64 {
        let ins = &self.config.instrument;
        ins.t0_us as f64
            + (t_program_s - self.recording_start_s) * (1.0 + ins.clock_ppm * 1e-6) * 1e6
    }

    /// When each block ran.
    pub fn blocks(&self) -> Vec<BlockTiming> {
        self.trajectory
            .segments
            .iter()
            .map(|s| {
                let b = &self.program.blocks[s.block];
                BlockTiming {
                    line: b.line,
                    n: b.n,
                    kind: s.kind,
                    start_s: s.t_start_s - self.recording_start_s,
                    end_s: s.t_end_s() - self.recording_start_s,
                    start_us: self.device_us(s.t_start_s),
                    end_us: self.device_us(s.t_end_s()),
                    from_mm: s.path.at(0.0),
                    to_mm: s.path.at(s.path.len()),
                }
            })
            .collect()
    }

    /// The samples one by one (constant memory): for long recordings written straight to a file
    /// or a QEMU scenario.
    pub fn samples(&self) -> Samples<'_> {
        Samples::new(self)
    }

    /// Write the recording as a QEMU scenario ([`jdbb_core::scenario`]): the encoders' raw
    /// counter values at every sample, which the `qemu` firmware build plays as its encoders
    /// (`scripts/qemu-run.sh --scenario FILE`), record k at k sample periods after the device's
    /// Start. The sample rate must give a whole number of µs per sample; `t0_us` is ignored (the
    /// device's clock starts at its Start). Returns the header written.
    pub fn write_scenario(
        &self,
        out: &mut impl std::io::Write,
    ) -> Result<jdbb_core::scenario::Header, SimError> {
        use jdbb_core::scenario::{encode_record, raw_of, Header};
        let period_us = 1e6 / self.config.instrument.sample_rate_hz;
        if (period_us - period_us.round()).abs() > 1e-9 || period_us < 1.0 {
            return Err(SimError::Config(format!(
                "a scenario needs a whole number of µs per sample; {} Hz gives {period_us} µs",
                self.config.instrument.sample_rate_hz
            )));
        }
        let n_samples = u32::try_from(self.len()).map_err(|_| {
            SimError::Config(format!(
                "{} samples: a scenario holds at most 2³² − 1",
                self.len()
            ))
        })?;
        let header = Header {
            period_us: period_us.round() as u32,
            n_samples,
        };
        let io = |e: std::io::Error| SimError::Write(e.to_string());
        out.write_all(&header.encode()).map_err(io)?;
        for s in self.samples() {
            let r = s?.row;
            out.write_all(&encode_record([raw_of(r.enc1), raw_of(r.enc2)]))
                .map_err(io)?;
        }
        Ok(header)
    }

    /// Record everything: rows and truth.
    pub fn run(&self) -> Result<Recording, SimError> {
        let mut rows = Vec::with_capacity(self.len());
        let mut samples = Vec::with_capacity(self.len());
        for s in self.samples() {
            let s = s?;
            rows.push(s.row);
            samples.push(s.truth);
        }
        let ins = &self.config.instrument;
        Ok(Recording {
            rows,
            truth: Truth {
                cycle_start_us: self.device_us(self.trajectory.cycle_start_s),
                feed_factor: self.config.machine.feed_override_pct / 100.0,
                clock_ppm: ins.clock_ppm,
                recording_start_program_s: self.recording_start_s,
                blocks: self.blocks(),
                samples,
            },
        })
    }
}

/// Read, plan and record `gcode` in one go.
pub fn simulate(gcode: &str, config: SimConfig) -> Result<Recording, SimError> {
    Simulation::new(gcode, config)?.run()
}
