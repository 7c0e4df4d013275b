//! The print-setting options `strata slice`, `simulate` and `print` share, and what they
//! make: the machine, the print settings, the toolpath settings and the job message.

use strata::geom::Triangle;
use strata::machine::{InfillPattern, MachineConfig, PrintSettings, Rate};
use strata::protocol::{JobOptions, JobSpec};
use strata::toolpath::{Seam, ToolpathConfig, MAX_BRIM_WIDTH_UM};

/// The print-setting options of `strata slice`, `simulate` and `print`.
#[derive(Debug, clap::Args)]
pub struct PrintArgs {
    /// Layer height in mm (default: the 0.2 mm profile).
    #[arg(long, value_name = "MM")]
    pub layer_height: Option<f64>,
    /// First layer height in mm (default: the 0.2 mm profile).
    #[arg(long, value_name = "MM")]
    pub first_layer_height: Option<f64>,
    /// Extrusion line width in mm (default 0.45).
    #[arg(long, value_name = "MM")]
    pub line_width: Option<f64>,
    /// Perimeter loops (default 2).
    #[arg(long, value_name = "N")]
    pub perimeters: Option<u8>,
    /// Sparse infill density in percent (default 20).
    #[arg(long, value_name = "PERCENT")]
    pub infill: Option<u8>,
    /// Sparse infill pattern (default zigzag).
    #[arg(long, value_enum)]
    pub pattern: Option<PatternArg>,
    /// Solid layers under top surfaces (default 4).
    #[arg(long, value_name = "N")]
    pub top_layers: Option<u8>,
    /// Solid layers over bottom surfaces (default 4).
    #[arg(long, value_name = "N")]
    pub bottom_layers: Option<u8>,
    /// Hotend temperature in C (default 200).
    #[arg(long, value_name = "C")]
    pub hotend_temp: Option<i16>,
    /// Bed temperature in C (default 60).
    #[arg(long, value_name = "C")]
    pub bed_temp: Option<i16>,
    /// Perimeter speed in mm/s (default 45).
    #[arg(long, value_name = "MM_S")]
    pub perimeter_speed: Option<f64>,
    /// Infill speed in mm/s (default 60).
    #[arg(long, value_name = "MM_S")]
    pub infill_speed: Option<f64>,
    /// Travel speed in mm/s (default 150).
    #[arg(long, value_name = "MM_S")]
    pub travel_speed: Option<f64>,
    /// First layer speed in mm/s (default 20).
    #[arg(long, value_name = "MM_S")]
    pub first_layer_speed: Option<f64>,
    /// Retraction length in mm (default 5, Bowden; 0 disables).
    #[arg(long, value_name = "MM")]
    pub retract_length: Option<f64>,
    /// Retraction speed in mm/s (default 45).
    #[arg(long, value_name = "MM_S")]
    pub retract_speed: Option<f64>,
    /// Absolute extrusion (M82) instead of relative (M83).
    #[arg(long)]
    pub absolute_e: bool,
    /// Print the external perimeter before the inner ones.
    #[arg(long)]
    pub outer_perimeter_first: bool,
    /// Where loops start (default rear).
    #[arg(long, value_enum)]
    pub seam: Option<SeamArg>,
    /// Skirt loops (default 1; 0 for none).
    #[arg(long, value_name = "N")]
    pub skirt_loops: Option<u8>,
    /// Gap between the skirt and the first layer in mm (default 3).
    #[arg(long, value_name = "MM")]
    pub skirt_distance: Option<f64>,
    /// Brim width in mm around the first layer's parts (default 0: none): as many loops as
    /// fit, floor(width / line width); the skirt goes around it.
    #[arg(long, value_name = "MM")]
    pub brim: Option<f64>,
    /// Build volume X,Y,Z in mm (default 220,220,250).
    #[arg(long, value_name = "X,Y,Z", value_delimiter = ',')]
    pub bed: Option<Vec<f64>>,
}

/// `--pattern` values.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum PatternArg {
    /// Parallel lines, all printed in the same direction.
    Lines,
    /// Lines joined into continuous runs.
    Zigzag,
    /// Lines in both directions on every layer.
    Grid,
}

/// `--seam` values.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum SeamArg {
    /// Rear-most vertex.
    Rear,
    /// Vertex nearest to the nozzle.
    Nearest,
}

/// A height option in mm to um, refused when not a positive finite number.
fn height_um(value: Option<f64>, default_um: i32, flag: &str) -> Result<i32, String> {
    match value {
        None => Ok(default_um),
        Some(v) if v.is_finite() && v > 0.0 && v < 1000.0 => Ok((v * 1000.0).round() as i32),
        Some(v) => Err(format!("--{flag} {v}: must be a positive height in mm")),
    }
}

/// A length option in mm to um: positive (or `zero_ok`), finite, below 1 m.
fn length_um(
    value: Option<f64>,
    default_um: i32,
    flag: &str,
    zero_ok: bool,
) -> Result<i32, String> {
    match value {
        None => Ok(default_um),
        Some(v) if v.is_finite() && (v > 0.0 || (zero_ok && v == 0.0)) && v < 1000.0 => {
            Ok((v * 1000.0).round() as i32)
        }
        Some(v) => Err(format!("--{flag} {v}: must be a positive length in mm")),
    }
}

/// The `--brim` width in mm to um: 0 to [`MAX_BRIM_WIDTH_UM`].
fn brim_um(value: Option<f64>, default_um: i32) -> Result<i32, String> {
    let max_mm = f64::from(MAX_BRIM_WIDTH_UM) / 1000.0;
    match value {
        None => Ok(default_um),
        Some(v) if v.is_finite() && (0.0..=max_mm).contains(&v) => Ok((v * 1000.0).round() as i32),
        Some(v) => Err(format!("--brim {v}: must be a brim width from 0 to {max_mm} mm")),
    }
}

/// A speed option in mm/s.
fn speed(value: Option<f64>, default: Rate, flag: &str) -> Result<Rate, String> {
    match value {
        None => Ok(default),
        Some(v) if v.is_finite() && v > 0.0 && v < 10_000.0 => Ok(Rate::from_num(v)),
        Some(v) => Err(format!("--{flag} {v}: must be a positive speed in mm/s")),
    }
}

/// The machine (default Ender-3, or `--bed`).
pub fn machine_of(args: &PrintArgs) -> Result<MachineConfig, String> {
    let mut machine = MachineConfig::default();
    if let Some(bed) = &args.bed {
        if bed.len() != 3 {
            return Err(format!("--bed: 3 sizes in mm expected (X,Y,Z), {} given", bed.len()));
        }
        for (slot, &v) in machine.build_volume_um.iter_mut().zip(bed) {
            *slot = length_um(Some(v), 0, "bed", false)?;
        }
    }
    Ok(machine)
}

/// Print settings from the defaults and the options, validated against `machine`.
pub fn settings_of(args: &PrintArgs, machine: &MachineConfig) -> Result<PrintSettings, String> {
    let d = PrintSettings::default();
    let mut s = d;
    s.layer_height_um = height_um(args.layer_height, d.layer_height_um, "layer-height")?;
    s.first_layer_height_um =
        height_um(args.first_layer_height, d.first_layer_height_um, "first-layer-height")?;
    s.line_width_um = length_um(args.line_width, d.line_width_um, "line-width", false)?;
    s.perimeters = args.perimeters.unwrap_or(d.perimeters);
    s.infill_percent = args.infill.unwrap_or(d.infill_percent);
    s.infill_pattern = match args.pattern {
        None => d.infill_pattern,
        Some(PatternArg::Lines) => InfillPattern::Lines,
        Some(PatternArg::Zigzag) => InfillPattern::Zigzag,
        Some(PatternArg::Grid) => InfillPattern::Grid,
    };
    s.top_layers = args.top_layers.unwrap_or(d.top_layers);
    s.bottom_layers = args.bottom_layers.unwrap_or(d.bottom_layers);
    s.hotend_temp_c = args.hotend_temp.unwrap_or(d.hotend_temp_c);
    s.bed_temp_c = args.bed_temp.unwrap_or(d.bed_temp_c);
    s.perimeter_speed_mm_s =
        speed(args.perimeter_speed, d.perimeter_speed_mm_s, "perimeter-speed")?;
    s.infill_speed_mm_s = speed(args.infill_speed, d.infill_speed_mm_s, "infill-speed")?;
    s.travel_speed_mm_s = speed(args.travel_speed, d.travel_speed_mm_s, "travel-speed")?;
    s.first_layer_speed_mm_s =
        speed(args.first_layer_speed, d.first_layer_speed_mm_s, "first-layer-speed")?;
    s.retract_length_um =
        length_um(args.retract_length, d.retract_length_um, "retract-length", true)?;
    s.retract_speed_mm_s = speed(args.retract_speed, d.retract_speed_mm_s, "retract-speed")?;
    s.validate(machine).map_err(|e| e.to_string())?;
    Ok(s)
}

/// Toolpath settings from the print settings and the toolpath-only options.
pub fn toolpath_config_of(
    args: &PrintArgs,
    machine: &MachineConfig,
    settings: &PrintSettings,
) -> Result<ToolpathConfig, String> {
    let mut cfg = ToolpathConfig::new(machine, settings);
    // Small layers slow down (then wait, lifted) to the printer's minimum layer time, as
    // they do when it slices them itself.
    cfg.min_layer_time_ms = strata::printer::board::MIN_LAYER_TIME_MS;
    cfg.outer_perimeter_last = !args.outer_perimeter_first;
    if let Some(seam) = args.seam {
        cfg.seam = match seam {
            SeamArg::Rear => Seam::Rear,
            SeamArg::Nearest => Seam::Nearest,
        };
    }
    cfg.skirt_loops = args.skirt_loops.unwrap_or(cfg.skirt_loops);
    cfg.skirt_distance_um =
        length_um(args.skirt_distance, cfg.skirt_distance_um, "skirt-distance", true)?;
    cfg.brim_width_um = brim_um(args.brim, cfg.brim_width_um)?;
    cfg.validate().map_err(|e| e.to_string())?;
    Ok(cfg)
}

/// Builds the job message from the settings flags.
pub fn job_of(args: &PrintArgs, tris: &[Triangle]) -> Result<JobSpec, String> {
    let machine = machine_of(args)?;
    let settings = settings_of(args, &machine)?;
    let cfg = toolpath_config_of(args, &machine, &settings)?;
    let top = tris.iter().map(Triangle::z_max).max().unwrap_or(0);
    Ok(JobSpec {
        settings,
        options: JobOptions {
            outer_perimeter_last: cfg.outer_perimeter_last,
            seam: matches!(cfg.seam, Seam::Nearest) as u8,
            skirt_loops: cfg.skirt_loops,
            skirt_distance_um: cfg.skirt_distance_um,
            brim_loops: u8::try_from(cfg.brim_loops()).map_err(|_| {
                format!("--brim: {} loops of this line width; at most 255", cfg.brim_loops())
            })?,
        },
        model_height_um: top,
        triangles: tris.len() as u32,
    })
}
