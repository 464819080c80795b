//! The sun: where it is (`--sun ELEVATION,AZIMUTH` or a place and a time) and how much light
//! reaches the ground from it on a clear day.
//!
//! **Directions.** Elevation is degrees above the horizon; azimuth is degrees from −Z toward
//! +X (the environment map's φ). Read as a compass, −Z is north and +X east (Blender's +Y
//! north exports as glTF's −Z), so a sun study's compass azimuth (clockwise from north) is
//! this azimuth.
//!
//! **Position from a place and a time** ([`solar_position`]): NOAA's *General Solar Position
//! Calculations* (the equations of NOAA's solar calculator spreadsheet, after Meeus,
//! *Astronomical Algorithms*): the sun's apparent longitude and declination, the equation of
//! time, the hour angle, then elevation (with NOAA's refraction correction) and azimuth.
//!
//! **Clear-sky irradiance** ([`clear_sky_sun`]): the extraterrestrial illuminance (the solar
//! illuminance constant, 127.5 klx) in this project's photometric watts (1 W = 683 lm, the
//! convention RGB renderers use: luminance Y of an RGB radiance in W/(sr·m²) is cd/m² ÷ 683),
//! white above the atmosphere, times the transmittance of Rayleigh scattering and aerosols
//! along the path through it, per channel at 610, 550 and 465 nm: Preetham, Shirley & Smits
//! 1999, *A Practical Analytic Model for Daylight*, Appendix A.2 (`τ_R = exp(−0.008735·λ^−4.08·m)`,
//! `τ_a = exp(−β·λ^−α·m)`, α = 1.3, β = 0.04608·T − 0.04586, λ in µm), with the relative air
//! mass m of Kasten & Young 1989. Ozone, water vapour and mixed gases, which that appendix also
//! lists, are left out (a few per cent in the visible).

use glam::{DVec3, Vec3};

use super::{LightKind, PunctualLight, Rgb};

/// Where the sun is: degrees above the horizon and from −Z toward +X.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SunPosition {
    pub elevation: f64,
    pub azimuth: f64,
}

impl SunPosition {
    /// Unit world direction toward the sun.
    pub fn toward(&self) -> DVec3 {
        let (e, a) = (self.elevation.to_radians(), self.azimuth.to_radians());
        DVec3::new(e.cos() * a.sin(), e.sin(), -e.cos() * a.cos())
    }

    /// A directional light from here of irradiance `irradiance` (W/m² on a surface facing it).
    pub fn light(&self, name: &str, irradiance: Rgb) -> PunctualLight {
        PunctualLight {
            name: name.to_string(),
            kind: LightKind::Directional,
            intensity: irradiance,
            position: Vec3::ZERO,
            direction: (-self.toward()).as_vec3(),
            range: None,
        }
    }
}

/// Extraterrestrial solar illuminance, lux (the "solar illuminance constant").
pub const SOLAR_ILLUMINANCE: f64 = 127_500.0;
/// Lumens per photometric watt.
pub const LUMENS_PER_WATT: f64 = 683.0;
/// Wavelengths (µm) standing for the R, G and B channels in the atmosphere's transmittance.
pub const CHANNEL_WAVELENGTHS: [f64; 3] = [0.610, 0.550, 0.465];

/// Relative optical air mass at a sun `elevation` degrees up (Kasten & Young 1989); `None`
/// below the horizon.
pub fn air_mass(elevation: f64) -> Option<f64> {
    if elevation <= 0.0 {
        return None;
    }
    let zenith = 90.0 - elevation;
    Some(1.0 / (zenith.to_radians().cos() + 0.50572 * (96.07995 - zenith).powf(-1.6364)))
}

/// The clear-sky sun's irradiance on a surface facing it, at `elevation` degrees and
/// turbidity `turbidity` (see the module docs); black below the horizon.
pub fn clear_sky_sun(elevation: f64, turbidity: f64) -> Rgb {
    let Some(m) = air_mass(elevation) else { return Rgb::ZERO };
    let beta = 0.04608 * turbidity - 0.04586;
    let top = SOLAR_ILLUMINANCE / LUMENS_PER_WATT;
    let channel = |lambda: f64| {
        let rayleigh = (-0.008735 * lambda.powf(-4.08) * m).exp();
        let aerosol = (-beta * lambda.powf(-1.3) * m).exp();
        (top * rayleigh * aerosol) as f32
    };
    Rgb::new(channel(CHANNEL_WAVELENGTHS[0]), channel(CHANNEL_WAVELENGTHS[1]), channel(CHANNEL_WAVELENGTHS[2]))
}

/// An instant: seconds since 1970-01-01T00:00:00Z (leap seconds ignored, as ISO dates do).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Instant(pub f64);

impl Instant {
    /// The Julian day.
    pub fn julian_day(self) -> f64 {
        self.0 / 86_400.0 + 2_440_587.5
    }
}

/// Days from 1970-01-01 to a proleptic Gregorian date (Hinnant's `days_from_civil`).
fn days_from_civil(year: i64, month: i64, day: i64) -> i64 {
    let y = if month <= 2 { year - 1 } else { year };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let mp = (month + 9) % 12;
    let doy = (153 * mp + 2) / 5 + day - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// Parses an ISO-8601 date and time with its offset: `2026-06-21T12:00:00Z`,
/// `2026-06-21T14:00+02:00`, seconds and their fraction optional. An offset is required: a
/// sun study's hour means nothing without one.
pub fn parse_time(s: &str) -> Result<Instant, String> {
    let bad =
        |why: &str| format!("{s:?} is not an ISO-8601 date and time with an offset ({why}); e.g. 2026-06-21T12:00:00Z");
    let (date, rest) = s.trim().split_once(['T', 't']).ok_or_else(|| bad("no 'T' between date and time"))?;
    let number = |t: &str, what: &str| t.parse::<i64>().map_err(|_| bad(what));
    let mut d = date.splitn(3, '-');
    let (year, month, day) = match (d.next(), d.next(), d.next()) {
        (Some(y), Some(m), Some(dd)) if y.len() == 4 && m.len() == 2 && dd.len() == 2 => {
            (number(y, "year")?, number(m, "month")?, number(dd, "day")?)
        }
        _ => return Err(bad("the date is not YYYY-MM-DD")),
    };
    let leap = (year % 4 == 0 && year % 100 != 0) || year % 400 == 0;
    let month_days = [31, if leap { 29 } else { 28 }, 31, 30, 31, 30, 31, 31, 30, 31, 30, 31];
    if !(1..=12).contains(&month) || day < 1 || day > month_days[(month - 1) as usize] {
        return Err(bad("no such day"));
    }
    let (clock, offset) = if let Some(c) = rest.strip_suffix(['Z', 'z']) {
        (c, 0)
    } else if let Some(i) = rest.rfind(['+', '-']) {
        let (c, o) = rest.split_at(i);
        let sign = if o.starts_with('-') { -1 } else { 1 };
        let (oh, om) = o[1..].split_once(':').unwrap_or((&o[1..], "0"));
        let (oh, om) = (number(oh, "offset hours")?, number(om, "offset minutes")?);
        if oh > 18 || om > 59 {
            return Err(bad("offset out of range"));
        }
        (c, sign * (oh * 3600 + om * 60))
    } else {
        return Err(bad("no offset: end with Z or ±HH:MM"));
    };
    let mut parts = clock.split(':');
    let hour = number(parts.next().unwrap_or(""), "hour")?;
    let minute = number(parts.next().ok_or_else(|| bad("no minutes"))?, "minute")?;
    let second: f64 = match parts.next() {
        Some(t) => t.parse().map_err(|_| bad("seconds"))?,
        None => 0.0,
    };
    if parts.next().is_some()
        || !(0..24).contains(&hour)
        || !(0..60).contains(&minute)
        || !(0.0..60.0).contains(&second)
    {
        return Err(bad("the time is not HH:MM[:SS]"));
    }
    let days = days_from_civil(year, month, day);
    Ok(Instant((days * 86_400 + hour * 3600 + minute * 60 - offset) as f64 + second))
}

/// The proleptic Gregorian date of a day count from 1970-01-01 (Hinnant's `civil_from_days`).
fn civil_from_days(z: i64) -> (i64, i64, i64) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let day = doy - (153 * mp + 2) / 5 + 1;
    let month = if mp < 10 { mp + 3 } else { mp - 9 };
    (yoe + era * 400 + (month <= 2) as i64, month, day)
}

/// `2026-06-21T12:00` (UTC, to the minute).
pub fn format_time(t: Instant) -> String {
    let minutes = (t.0 / 60.0).floor() as i64;
    let (days, minute_of_day) = (minutes.div_euclid(1440), minutes.rem_euclid(1440));
    let (y, m, d) = civil_from_days(days);
    format!("{y:04}-{m:02}-{d:02}T{:02}:{:02}", minute_of_day / 60, minute_of_day % 60)
}

/// The sun's apparent position seen from latitude `lat`, longitude `lon` (degrees, north and
/// east positive) at `when`: NOAA's equations (module docs).
pub fn solar_position(lat: f64, lon: f64, when: Instant) -> SunPosition {
    let jd = when.julian_day();
    let jc = (jd - 2_451_545.0) / 36_525.0;
    let geom_mean_long = (280.46646 + jc * (36000.76983 + jc * 0.0003032)).rem_euclid(360.0);
    let geom_mean_anom = 357.52911 + jc * (35999.05029 - 0.0001537 * jc);
    let eccentricity = 0.016708634 - jc * (0.000042037 + 0.0000001267 * jc);
    let m = geom_mean_anom.to_radians();
    let centre = m.sin() * (1.914602 - jc * (0.004817 + 0.000014 * jc))
        + (2.0 * m).sin() * (0.019993 - 0.000101 * jc)
        + (3.0 * m).sin() * 0.000289;
    let true_long = geom_mean_long + centre;
    let omega = (125.04 - 1934.136 * jc).to_radians();
    let apparent_long = true_long - 0.00569 - 0.00478 * omega.sin();
    let mean_obliquity = 23.0 + (26.0 + (21.448 - jc * (46.815 + jc * (0.00059 - jc * 0.001813))) / 60.0) / 60.0;
    let obliquity = (mean_obliquity + 0.00256 * omega.cos()).to_radians();
    let declination = (obliquity.sin() * apparent_long.to_radians().sin()).asin();
    let y = (obliquity / 2.0).tan().powi(2);
    let l0 = geom_mean_long.to_radians();
    let equation_of_time = 4.0
        * (y * (2.0 * l0).sin() - 2.0 * eccentricity * m.sin() + 4.0 * eccentricity * y * m.sin() * (2.0 * l0).cos()
            - 0.5 * y * y * (4.0 * l0).sin()
            - 1.25 * eccentricity * eccentricity * (2.0 * m).sin())
        .to_degrees();
    let utc_minutes = (when.0.rem_euclid(86_400.0)) / 60.0;
    let true_solar_time = (utc_minutes + equation_of_time + 4.0 * lon).rem_euclid(1440.0);
    // NOAA's IF(TST/4 < 0, TST/4 + 180, TST/4 − 180), with TST already in [0, 1440).
    let hour_angle = true_solar_time / 4.0 - 180.0;
    let (phi, ha) = (lat.to_radians(), hour_angle.to_radians());
    let cos_zenith = (phi.sin() * declination.sin() + phi.cos() * declination.cos() * ha.cos()).clamp(-1.0, 1.0);
    let zenith = cos_zenith.acos();
    let elevation = 90.0 - zenith.to_degrees();
    let azimuth = {
        let denominator = phi.cos() * zenith.sin();
        let a = if denominator.abs() < 1e-12 {
            0.0
        } else {
            ((phi.sin() * cos_zenith - declination.sin()) / denominator).clamp(-1.0, 1.0).acos().to_degrees()
        };
        if hour_angle > 0.0 { (a + 180.0).rem_euclid(360.0) } else { (540.0 - a).rem_euclid(360.0) }
    };
    SunPosition { elevation: elevation + refraction(elevation), azimuth }
}

/// NOAA's approximate atmospheric refraction at a true elevation of `e` degrees, degrees.
fn refraction(e: f64) -> f64 {
    let t = e.to_radians().tan();
    let arcsec = if e > 85.0 {
        0.0
    } else if e > 5.0 {
        58.1 / t - 0.07 / t.powi(3) + 0.000086 / t.powi(5)
    } else if e > -0.575 {
        1735.0 + e * (-518.2 + e * (103.4 + e * (-12.79 + e * 0.711)))
    } else {
        -20.772 / t
    };
    arcsec / 3600.0
}

/// Degrees between two sun positions.
pub fn angle_between(a: &SunPosition, b: &SunPosition) -> f64 {
    a.toward().angle_between(b.toward()).to_degrees()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sun study. Expected values from two independent implementations, run
    /// outside this project (Python 3.11):
    /// * NOAA's equations as the `astral` package (3.2) codes them —
    ///   `astral.sun.elevation/azimuth(Observer(48.85, 2.35), datetime(2026,6,21,12,tzinfo=utc))`;
    /// * NREL's SPA (Reda & Andreas 2004, ±0.0003°) as `pvlib` (0.16.1) codes it —
    ///   `pvlib.solarposition.spa_python(time, 48.85, 2.35)`: `apparent_elevation`, `azimuth`.
    ///
    /// NOAA's equations are within 0.0167° of SPA between ±72° latitude (NOAA's own
    /// statement), so 0.1° is a loose bound for either; what it catches is a wrong sign,
    /// axis, time zone or hour-angle branch (each of which moves the sun by degrees).
    #[test]
    fn paris_at_noon_utc_on_midsummer_day_matches_noaa_and_spa() {
        let when = parse_time("2026-06-21T12:00:00Z").expect("a time");
        let ours = solar_position(48.85, 2.35, when);
        for (source, elevation, azimuth) in REFERENCES {
            let theirs = SunPosition { elevation, azimuth };
            let off = angle_between(&ours, &theirs);
            assert!(off < 0.1, "{source}: ours {ours:?}, theirs {theirs:?}: {off}°");
            assert!((ours.elevation - elevation).abs() < 0.1 && (ours.azimuth - azimuth).abs() < 0.1, "{source}");
        }
    }

    /// See [`paris_at_noon_utc_on_midsummer_day_matches_noaa_and_spa`].
    const REFERENCES: [(&str, f64, f64); 2] = [
        ("NOAA (astral 3.2)", 64.55173230226353, 184.0454215174768),
        ("SPA (pvlib 0.16.1)", 64.55078337365977, 184.04912838743962),
    ];

    /// By hand: at the March equinox, on the equator, at local solar noon, the sun is
    /// overhead to within the declination's and the equation of time's small offsets; at
    /// 18:00 solar time it sets due west.
    #[test]
    fn the_equator_at_the_equinox_sees_the_sun_overhead_at_noon_and_setting_west() {
        // 2026-03-20 14:46 UTC is the equinox; the equation of time is −7.5 min then.
        let noon = parse_time("2026-03-20T12:07:30Z").expect("a time");
        let p = solar_position(0.0, 0.0, noon);
        assert!(p.elevation > 89.5, "{p:?}");
        let evening = parse_time("2026-03-20T18:07:30Z").expect("a time");
        let p = solar_position(0.0, 0.0, evening);
        assert!(p.elevation.abs() < 1.0 && (p.azimuth - 270.0).abs() < 1.0, "{p:?}");
    }

    #[test]
    fn times_parse_with_offsets_and_bad_ones_are_refused() {
        let z = parse_time("2026-06-21T12:00:00Z").expect("Z");
        assert_eq!(z.0, 1_782_043_200.0);
        assert_eq!(parse_time("2026-06-21T14:00+02:00").expect("offset"), z);
        assert_eq!(parse_time("2026-06-21T07:30:00.5-04:30").expect("negative offset").0, z.0 + 0.5);
        assert_eq!(parse_time("1970-01-01T00:00Z").expect("epoch").0, 0.0);
        assert!((z.julian_day() - 2_461_213.0).abs() < 1e-9);
        assert_eq!(format_time(z), "2026-06-21T12:00");
        assert_eq!(format_time(parse_time("2024-02-29T23:59:59Z").expect("leap day")), "2024-02-29T23:59");
        for bad in
            ["2026-06-21T12:00:00", "2026-02-30T12:00Z", "2026-06-21 12:00Z", "21/06/2026T12:00Z", "2026-06-21T25:00Z"]
        {
            assert!(parse_time(bad).is_err(), "{bad}");
        }
    }

    /// The sun's direction: elevation up from the horizon, azimuth from −Z toward +X.
    #[test]
    fn azimuth_runs_from_minus_z_toward_plus_x() {
        let d = |e, a| SunPosition { elevation: e, azimuth: a }.toward();
        assert!(d(90.0, 0.0).abs_diff_eq(DVec3::Y, 1e-12));
        assert!(d(0.0, 0.0).abs_diff_eq(DVec3::NEG_Z, 1e-12));
        assert!(d(0.0, 90.0).abs_diff_eq(DVec3::X, 1e-12));
        let light = SunPosition { elevation: 30.0, azimuth: 45.0 }.light("sun", Rgb::ONE);
        assert!(light.direction.dot(d(30.0, 45.0).as_vec3()) < -0.999_999);
    }

    /// Air mass 1 overhead, ~2 at 30°, ~38 at the horizon (Kasten & Young's table); the
    /// clear sun reddens as it sinks and dims with turbidity.
    #[test]
    fn the_clear_sky_sun_follows_air_mass_and_turbidity() {
        assert!((air_mass(90.0).expect("up") - 1.0).abs() < 1e-3);
        assert!((air_mass(30.0).expect("up") - 1.995).abs() < 0.01);
        assert!((air_mass(1e-9).expect("up") - 37.9).abs() < 0.5);
        assert_eq!(air_mass(-1.0), None);
        let high = clear_sky_sun(60.0, 3.0);
        let low = clear_sky_sun(5.0, 3.0);
        assert!(high.z / high.x > low.z / low.x && low.x > low.z);
        assert!(clear_sky_sun(60.0, 6.0).y < high.y);
        // Overhead at turbidity 3: 186.7 W/m² above the atmosphere, τ ≈ 0.74 at 550 nm.
        assert!((clear_sky_sun(90.0, 3.0).y / 138.4 - 1.0).abs() < 0.01, "{}", clear_sky_sun(90.0, 3.0));
    }
}
