//! The CSV file and markdown table of `psao bench`, with plain statements
//! of where PSAO wins and loses.

use std::fmt::Write as _;
use std::path::Path;

use super::measure::Settings;
use super::model::{Method, Row, SceneResult};

/// The PSNR margin over SAO the accuracy issue targets for PSAO-1024.
pub const TARGET_DB_OVER_SAO: f64 = 3.0;

/// Writes `bench.csv` and `bench.md`; returns the files written.
pub fn write(out: &Path, s: &Settings, results: &[SceneResult]) -> std::io::Result<Vec<String>> {
    let csv = out.join("bench.csv");
    std::fs::write(&csv, csv_text(results))?;
    let md = out.join("bench.md");
    std::fs::write(&md, markdown(s, results))?;
    Ok(vec![csv.display().to_string(), md.display().to_string()])
}

/// Whether the server's tick fits its period on this machine (PSAO).
fn keeps_rate(row: &Row) -> Option<bool> {
    match (row.method, row.server_ms) {
        (Method::Psao { rate, .. }, Some(ms)) => Some(ms <= 1000.0 / rate as f64),
        _ => None,
    }
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or(String::new(), |v| format!("{v:.digits$}"))
}

/// The CSV: one line per scene and configuration.
pub fn csv_text(results: &[SceneResult]) -> String {
    let mut t = String::from(
        "scene,method,label,density,rate_hz,rays_per_pixel,points,server_ms,keeps_rate,client_ms,extra_ms,mbit_s,rmse,psnr_db,ssim,flip,setup_s,keyframe_bytes,unknown_px,dark_where_open_px,dropped_points\n",
    );
    for r in results {
        for row in &r.rows {
            let (kind, density, rate, rays) = match row.method {
                Method::Psao {
                    density,
                    rate,
                    budget,
                } => (
                    if budget { "psao-budget" } else { "psao" },
                    density.to_string(),
                    rate.to_string(),
                    String::new(),
                ),
                Method::Rtao { rays } => ("rtao", String::new(), String::new(), rays.to_string()),
                Method::Sao => ("sao", String::new(), String::new(), String::new()),
            };
            let _ = writeln!(
                t,
                "{},{kind},{},{density},{rate},{rays},{},{},{},{:.4},{},{},{:.6},{:.3},{:.5},{:.5},{},{},{},{:.6},{}",
                r.name,
                row.method.label(),
                row.points.map_or(String::new(), |p| p.to_string()),
                opt(row.server_ms, 4),
                keeps_rate(row).map_or(String::new(), |k| k.to_string()),
                row.client_ms,
                opt(row.extra_ms, 4),
                opt(row.mbit_s, 4),
                row.rmse,
                row.psnr,
                row.ssim,
                row.flip,
                opt(row.setup_s, 3),
                row.keyframe_bytes.map_or(String::new(), |b| b.to_string()),
                row.unknown_px,
                row.breakdown.dark_where_open_px,
                row.dropped.map_or(String::new(), |d| d.to_string()),
            );
        }
    }
    t
}

/// The markdown report: per scene a table and the verdicts.
pub fn markdown(s: &Settings, results: &[SceneResult]) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "Settings: {}x{} pixels, {} frames over each camera path, reference {} closest-hit rays per pixel (radius {}), PSAO {} rays per point traced on the {} ({}; {}; {}; {}; {}; {}; {}); client times are the AO work per frame on {} threads, the median of {} runs back to back.\n",
        s.width,
        s.height,
        s.frames,
        s.reference_rays,
        s.radius,
        s.point_rays,
        match (s.backend, s.gpu_single_rays) {
            (super::Backend::Cpu, _) => "CPU backend",
            (super::Backend::Gpu, false) => "GPU backend, whole points at a time",
            (super::Backend::Gpu, true) => "GPU backend, single rays at a time",
        },
        if s.fill_buried {
            "buried points take their visible neighbours' AO"
        } else {
            "buried points traced: --no-fill-buried"
        },
        if s.bind_space {
            "deforming meshes' points in bind space"
        } else {
            "deforming meshes' points posed: --posed-deforming"
        },
        if s.overflow {
            "full cells continue in overflow chains"
        } else {
            "points beyond a full cell dropped: --no-overflow"
        },
        if s.fill_gaps {
            "gaps on thin strips filled"
        } else {
            "elimination's points alone: --no-gap-fill"
        },
        if s.lead {
            "the scene posed one period plus the network's delay ahead of each tick"
        } else {
            "the scene posed at each tick: --no-lead"
        },
        match s.settle_steps {
            0 => "points motion has left held within the send threshold: --settle-steps 0"
                .to_string(),
            n => format!(
                "points whose AO stopped changing sent {n} or more steps (1/255) from what clients hold"
            ),
        },
        if s.hidden_test {
            "the client leaves out points its view shows hidden behind a surface facing the pixel (spec/wire-format.md 7.3.1)"
        } else {
            "the client weighs every point by eq. 2-3 (spec/wire-format.md 7.3): --no-hidden-test"
        },
        std::thread::available_parallelism().map_or(1, |n| n.get()),
        super::measure::TIMED_RUNS
    );
    for r in results {
        let _ = writeln!(
            t,
            "### {}\n\n{} triangles, {:.0}% of pixels covered, reference traced in {:.1} s.\n",
            r.name,
            r.triangles,
            r.coverage * 100.0,
            r.reference_s
        );
        t.push_str("| configuration | points | setup s | keyframe kB | server ms/tick | client ms/frame | of which decode (PSAO) / BVH build not included (RTAO) | Mbit/s | RMSE | PSNR dB | SSIM | FLIP |\n");
        t.push_str("|---|---|---|---|---|---|---|---|---|---|---|---|\n");
        for row in &r.rows {
            let _ = writeln!(
                t,
                "| {} | {} | {} | {} | {} | {:.2} | {} | {} | {:.4} | {:.2} | {:.4} | {:.4} |",
                row.method.label(),
                match (row.points, row.dropped) {
                    (Some(p), Some(d)) if d > 0 => format!("{p} ({d} dropped)"),
                    (Some(p), _) => p.to_string(),
                    (None, _) => "-".into(),
                },
                row.setup_s.map_or("-".into(), |v| format!("{v:.2}")),
                row.keyframe_bytes
                    .map_or("-".into(), |b| format!("{:.1}", b as f64 / 1e3)),
                row.server_ms.map_or("-".into(), |v| {
                    let slow = if keeps_rate(row) == Some(false) {
                        " (slower than the rate)"
                    } else {
                        ""
                    };
                    format!("{v:.1}{slow}")
                }),
                row.client_ms,
                row.extra_ms.map_or("-".into(), |v| format!("{v:.2}")),
                row.mbit_s.map_or("-".into(), |v| format!("{v:.2}")),
                row.rmse,
                row.psnr,
                row.ssim,
                row.flip,
            );
        }
        t.push('\n');
        for line in verdicts(s, r) {
            let _ = writeln!(t, "- {line}");
        }
        t.push('\n');
    }
    t
}

/// How many dB `to` lies above `from`: 0 where they are equal, both
/// infinite included (two exact images, as on AnimatedTriangle), where
/// the plain difference is NaN.
fn db_gain(to: f64, from: f64) -> f64 {
    if to == from { 0.0 } else { to - from }
}

/// Plain statements about one scene's rows.
pub fn verdicts(s: &Settings, r: &SceneResult) -> Vec<String> {
    let mut out = Vec::new();
    let rate = s.rates[0];
    let sweep: Vec<&Row> = r
        .rows
        .iter()
        .filter(
            |row| matches!(row.method, Method::Psao { rate: q, budget: false, .. } if q == rate),
        )
        .collect();
    if sweep.len() >= 2 {
        let falls = sweep.windows(2).all(|w| w[1].rmse <= w[0].rmse);
        let list: Vec<String> = sweep
            .iter()
            .map(|row| match row.method {
                Method::Psao { density, .. } => format!("N={density}: {:.2} dB", row.psnr),
                _ => String::new(),
            })
            .collect();
        out.push(format!(
            "PSAO error as N grows at {rate} Hz: {} ({}).",
            if falls {
                "falls at every step"
            } else {
                "does **not** fall at every step"
            },
            list.join(", ")
        ));
    }
    let focus = s.focus_density();
    let psao = r.rows.iter().find(|row| {
        row.method
            == Method::Psao {
                density: focus,
                rate,
                budget: false,
            }
    });
    let sao = r.rows.iter().find(|row| row.method == Method::Sao);
    if let (Some(p), Some(q)) = (psao, sao) {
        let margin = db_gain(p.psnr, q.psnr);
        out.push(format!(
            "PSAO-{focus} @{rate} Hz against SAO: {:+.2} dB PSNR ({:.2} against {:.2} dB), SSIM {:.4} against {:.4}; target +{TARGET_DB_OVER_SAO} dB: **{}**. Client time {:.2} against {:.2} ms ({:.2}x).",
            margin,
            p.psnr,
            q.psnr,
            p.ssim,
            q.ssim,
            if margin >= TARGET_DB_OVER_SAO { "met" } else { "not met" },
            p.client_ms,
            q.client_ms,
            p.client_ms / q.client_ms.max(1e-9),
        ));
    }
    if let Some(p) = psao {
        let nearest = r
            .rows
            .iter()
            .filter(|row| matches!(row.method, Method::Rtao { .. }))
            .min_by(|a, b| {
                (a.client_ms / p.client_ms)
                    .ln()
                    .abs()
                    .total_cmp(&(b.client_ms / p.client_ms).ln().abs())
            });
        if let Some(k) = nearest {
            out.push(format!(
                "Nearest in client time, PSAO-{focus} ({:.2} ms) {} {} ({:.2} ms, {:.2}x PSAO's time) by {:.2} dB PSNR ({:.2} against {:.2} dB).",
                p.client_ms,
                if p.psnr >= k.psnr { "beats" } else { "loses to" },
                k.method.label(),
                k.client_ms,
                k.client_ms / p.client_ms.max(1e-9),
                db_gain(p.psnr, k.psnr).abs(),
                p.psnr,
                k.psnr
            ));
        }
        // RTAO rows above PSAO's PSNR, with more (or not more) client time.
        let rtao_above = |more_time: bool| -> Vec<String> {
            r.rows
                .iter()
                .filter(|row| {
                    matches!(row.method, Method::Rtao { .. })
                        && row.psnr > p.psnr
                        && (row.client_ms > p.client_ms) == more_time
                })
                .map(|row| {
                    format!(
                        "{} ({:.2} dB at {:.2} ms)",
                        row.method.label(),
                        row.psnr,
                        row.client_ms
                    )
                })
                .collect()
        };
        let (better, cheaper) = (rtao_above(true), rtao_above(false));
        if !cheaper.is_empty() {
            out.push(format!(
                "Per-pixel RTAO beats PSAO-{focus} in less client time: {}.",
                cheaper.join(", ")
            ));
        }
        if !better.is_empty() {
            out.push(format!(
                "Per-pixel RTAO with more client time beats PSAO-{focus}: {}.",
                better.join(", ")
            ));
        }
    }
    let shares = |row: &Row| {
        let top: Vec<String> = row
            .breakdown
            .by_instance
            .iter()
            .take(3)
            .map(|(id, share)| {
                let kind = r.kinds.get(*id as usize).map_or("?", |k| k.as_str());
                format!("instance {id} ({kind}) {:.0}%", share * 100.0)
            })
            .collect();
        let causes: Vec<String> = row
            .breakdown
            .open_causes
            .iter()
            .filter(|(_, share)| *share > 0.0)
            .map(|(name, share)| format!("{name} {:.1}%", share * 100.0))
            .collect();
        let causes = if causes.is_empty() {
            String::new()
        } else {
            format!(" ({})", causes.join(", "))
        };
        format!(
            "{}: {}; {:.0}% in pixels left open where the reference is dark{causes}; {:.0}% in the {:.3}% of pixels at least {} darker than an open reference (above {})",
            row.method.label(),
            top.join(", "),
            row.breakdown.open_where_dark * 100.0,
            row.breakdown.dark_where_open * 100.0,
            row.breakdown.dark_where_open_px * 100.0,
            super::model::DARKER,
            super::model::OPEN
        )
    };
    for b in r
        .rows
        .iter()
        .filter(|row| matches!(row.method, Method::Psao { budget: true, .. }))
    {
        let Method::Psao { density, rate, .. } = b.method else {
            continue;
        };
        let plain = r.rows.iter().find(|row| {
            row.method
                == Method::Psao {
                    density,
                    rate,
                    budget: false,
                }
        });
        if let (Some(p), Some(bs), Some(ps)) = (plain, b.server_ms, plain.and_then(|p| p.server_ms))
        {
            out.push(format!(
                "{}: server {bs:.1} against {ps:.1} ms per tick ({:.2}x; {}), {:.2} against {:.2} dB PSNR ({:+.2} dB), {:.3} against {:.3} Mbit/s, {:.0} against {:.0} rays a tick ({:.2}x); {} of {} ticks over the period (longest {:.1} ms); no point waited more than {} ticks.",
                b.method.label(),
                bs / ps,
                if bs <= 1000.0 / rate as f64 { "keeps the rate" } else { "slower than the rate" },
                b.psnr,
                p.psnr,
                db_gain(b.psnr, p.psnr),
                b.mbit_s.unwrap_or(0.0),
                p.mbit_s.unwrap_or(0.0),
                b.rays_per_tick.unwrap_or(0.0),
                p.rays_per_tick.unwrap_or(0.0),
                b.rays_per_tick.unwrap_or(0.0) / p.rays_per_tick.unwrap_or(0.0).max(1.0),
                b.ticks_over.map_or(0, |t| t.0),
                b.ticks_over.map_or(0, |t| t.1),
                b.ticks_over.map_or(0.0, |t| t.2),
                b.worst_wait.unwrap_or(0)
            ));
        }
    }
    if let (Some(p), Some(q)) = (psao, sao) {
        out.push(format!(
            "Where the squared error lies: {}. {}.",
            shares(p),
            shares(q)
        ));
    }
    let stale: Vec<String> = r
        .rows
        .iter()
        .filter_map(|row| match row.method {
            Method::Psao {
                density,
                rate: q,
                budget: false,
            } if density == focus && q != rate => Some(format!(
                "{q} Hz: {:.2} dB, {:.2} Mbit/s",
                row.psnr,
                row.mbit_s.unwrap_or(0.0)
            )),
            _ => None,
        })
        .collect();
    if !stale.is_empty() {
        out.push(format!(
            "Lower server rates for PSAO-{focus} (the client keeps the last received frame): {}.",
            stale.join("; ")
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::db_gain;

    #[test]
    fn a_psnr_change_between_two_exact_images_is_none() {
        assert_eq!(db_gain(f64::INFINITY, f64::INFINITY), 0.0);
        assert_eq!(db_gain(45.5, 46.0), -0.5);
        assert_eq!(db_gain(f64::INFINITY, 40.0), f64::INFINITY);
        assert_eq!(db_gain(40.0, f64::INFINITY), f64::NEG_INFINITY);
    }
}
