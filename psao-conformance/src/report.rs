//! Case results and how they are printed: a line per case, a summary, JSON
//! and JUnit XML.

use std::fmt::Write as _;
use std::time::Duration;

use serde::Serialize;

/// How a case ended.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(tag = "outcome", content = "detail", rename_all = "snake_case")]
pub enum Outcome {
    /// The implementation did what the spec says.
    Passed,
    /// It did something else: what was seen.
    Failed(String),
    /// The case does not apply (the implementation chose an option the
    /// case needs not): why.
    Skipped(String),
}

impl Outcome {
    /// The outcome of a case written as a `Result`: `Ok` passes, an error
    /// starting with `SKIP:` skips with the rest as the reason, any other
    /// error fails with it.
    pub fn of(r: Result<(), String>) -> Outcome {
        match r {
            Ok(()) => Outcome::Passed,
            Err(e) => match e.strip_prefix("SKIP:") {
                Some(why) => Outcome::Skipped(why.to_string()),
                None => Outcome::Failed(e),
            },
        }
    }
}

/// One case's result.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct CaseResult {
    /// Stable id, e.g. `uplink.rate`.
    pub id: &'static str,
    /// The spec section it checks, e.g. `session.md 6`.
    pub section: &'static str,
    /// What it checks.
    pub title: &'static str,
    /// How it ended.
    #[serde(flatten)]
    pub outcome: Outcome,
    /// How long it took, in milliseconds (the last attempt).
    pub millis: u64,
    /// Attempts made: a case whose connection ended without any
    /// application close (a QUIC stateless reset, a lost close) is
    /// inconclusive and runs again, up to 3 times.
    pub attempts: u32,
}

impl CaseResult {
    /// The result of a case that ran for `took`.
    pub fn new(
        id: &'static str,
        section: &'static str,
        title: &'static str,
        outcome: Outcome,
        took: Duration,
    ) -> CaseResult {
        CaseResult {
            id,
            section,
            title,
            outcome,
            millis: took.as_millis() as u64,
            attempts: 1,
        }
    }

    /// The case's line: `PASS id (section): title`, with the detail of a
    /// failure or skip.
    pub fn line(&self) -> String {
        let mut head = format!("{} ({}): {}", self.id, self.section, self.title);
        if self.attempts > 1 {
            head.push_str(&format!(" [attempt {}]", self.attempts));
        }
        match &self.outcome {
            Outcome::Passed => format!("PASS {head}"),
            Outcome::Failed(why) => format!("FAIL {head}: {why}"),
            Outcome::Skipped(why) => format!("SKIP {head}: {why}"),
        }
    }
}

/// All results of a run.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Report {
    /// What was tested (an address, a name).
    pub target: String,
    /// The results, in the order the cases ran.
    pub cases: Vec<CaseResult>,
}

impl Report {
    /// Cases passed, failed, skipped.
    pub fn counts(&self) -> (usize, usize, usize) {
        let n = |f: fn(&Outcome) -> bool| self.cases.iter().filter(|c| f(&c.outcome)).count();
        (
            n(|o| *o == Outcome::Passed),
            n(|o| matches!(o, Outcome::Failed(_))),
            n(|o| matches!(o, Outcome::Skipped(_))),
        )
    }

    /// Whether no case failed.
    pub fn ok(&self) -> bool {
        self.counts().1 == 0
    }

    /// The summary line: `N passed, N failed, N skipped`.
    pub fn summary(&self) -> String {
        let (p, f, s) = self.counts();
        format!("{p} passed, {f} failed, {s} skipped")
    }

    /// The result of case `id`.
    pub fn case(&self, id: &str) -> Option<&CaseResult> {
        self.cases.iter().find(|c| c.id == id)
    }

    /// The report as JSON: `{"target": .., "summary": .., "cases": [..]}`.
    pub fn to_json(&self) -> String {
        #[derive(Serialize)]
        struct Doc<'a> {
            target: &'a str,
            summary: String,
            passed: usize,
            failed: usize,
            skipped: usize,
            cases: &'a [CaseResult],
        }
        let (passed, failed, skipped) = self.counts();
        let doc = Doc {
            target: &self.target,
            summary: self.summary(),
            passed,
            failed,
            skipped,
            cases: &self.cases,
        };
        serde_json::to_string_pretty(&doc).unwrap_or_else(|e| format!("{{\"error\": \"{e}\"}}"))
    }

    /// The report as JUnit XML (one `testsuite`, a `testcase` per case,
    /// `failure` and `skipped` elements), as CI systems read it.
    pub fn to_junit(&self, suite: &str) -> String {
        let (_, failed, skipped) = self.counts();
        let secs: f64 = self.cases.iter().map(|c| c.millis as f64 / 1e3).sum();
        let mut x = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
        let _ = writeln!(
            x,
            "<testsuite name=\"{}\" tests=\"{}\" failures=\"{failed}\" skipped=\"{skipped}\" time=\"{secs:.3}\">",
            escape(suite),
            self.cases.len()
        );
        for c in &self.cases {
            let _ = write!(
                x,
                "  <testcase classname=\"{}\" name=\"{} ({})\" time=\"{:.3}\"",
                escape(suite),
                escape(c.id),
                escape(c.section),
                c.millis as f64 / 1e3
            );
            match &c.outcome {
                Outcome::Passed => x.push_str("/>\n"),
                Outcome::Failed(why) => {
                    let _ = writeln!(
                        x,
                        ">\n    <failure message=\"{}\">{}</failure>\n  </testcase>",
                        escape(why),
                        escape(c.title)
                    );
                }
                Outcome::Skipped(why) => {
                    let _ = writeln!(
                        x,
                        ">\n    <skipped message=\"{}\"/>\n  </testcase>",
                        escape(why)
                    );
                }
            }
        }
        x.push_str("</testsuite>\n");
        x
    }
}

/// XML text and attribute escaping.
fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for ch in s.chars() {
        match ch {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c if c.is_control() && c != '\n' && c != '\t' => {
                let _ = write!(out, "&#x{:x};", c as u32);
            }
            c => out.push(c),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Report {
        let r = |id, outcome| {
            CaseResult::new(
                id,
                "session.md 6",
                "a <case>",
                outcome,
                Duration::from_millis(12),
            )
        };
        Report {
            target: "127.0.0.1:4433".into(),
            cases: vec![
                r("a", Outcome::Passed),
                r(
                    "b",
                    Outcome::Failed("closed with \"internal_error\" & more".into()),
                ),
                r("c", Outcome::Skipped("no digests".into())),
            ],
        }
    }

    #[test]
    fn summary_json_and_junit_say_the_same() {
        let rep = sample();
        assert_eq!(rep.summary(), "1 passed, 1 failed, 1 skipped");
        assert!(!rep.ok());
        let json: serde_json::Value = serde_json::from_str(&rep.to_json()).unwrap();
        assert_eq!(json["failed"], 1);
        assert_eq!(json["cases"][1]["outcome"], "failed");
        assert_eq!(
            json["cases"][1]["detail"],
            "closed with \"internal_error\" & more"
        );
        let xml = rep.to_junit("psao");
        assert!(
            xml.contains("tests=\"3\" failures=\"1\" skipped=\"1\""),
            "{xml}"
        );
        assert!(xml.contains("message=\"closed with &quot;internal_error&quot; &amp; more\""));
        assert!(xml.contains("a &lt;case&gt;"));
        assert_eq!(xml.matches("<testcase").count(), 3);
        assert!(rep.cases[1].line().starts_with("FAIL b (session.md 6)"));
    }
}
