//! What the examples share: reading correspondences from a text file.

use std::path::Path;

/// One correspondence per line, `sx sy sz tx ty tz` (whitespace- or comma-separated; blank
/// lines and lines starting with `#` are skipped). Errors name the file and line.
#[allow(dead_code)] // each example uses one of the readers
pub fn read_rows(path: &Path) -> Result<Vec<[f64; 6]>, Box<dyn std::error::Error>> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut rows = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<f64> = line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|s| !s.is_empty())
            .map(str::parse)
            .collect::<Result<_, _>>()
            .map_err(|e| format!("{}:{}: {e}", path.display(), n + 1))?;
        let row: [f64; 6] = v.try_into().map_err(|v: Vec<f64>| {
            format!(
                "{}:{}: expected 6 numbers, got {}",
                path.display(),
                n + 1,
                v.len()
            )
        })?;
        rows.push(row);
    }
    Ok(rows)
}

/// One point per line, `x y z` (as [`read_rows`]). Errors name the file and line.
#[allow(dead_code)] // each example uses one of the readers
pub fn read_points(path: &Path) -> Result<Vec<[f64; 3]>, Box<dyn std::error::Error>> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut points = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let v: Vec<f64> = line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|s| !s.is_empty())
            .map(str::parse)
            .collect::<Result<_, _>>()
            .map_err(|e| format!("{}:{}: {e}", path.display(), n + 1))?;
        let p: [f64; 3] = v.try_into().map_err(|v: Vec<f64>| {
            format!(
                "{}:{}: expected 3 numbers, got {}",
                path.display(),
                n + 1,
                v.len()
            )
        })?;
        points.push(p);
    }
    Ok(points)
}
