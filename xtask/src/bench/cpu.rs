//! The machine and build a benchmark figure came from: the CPU as `/proc/cpuinfo` names it,
//! its CPU count and widest SIMD level, and the cargo profile.

/// The cargo profile this binary was built with, as far as it can tell: `dev` keeps debug
/// assertions on (see the workspace `Cargo.toml`), `release` turns them off.
pub fn build_profile() -> &'static str {
    if cfg!(debug_assertions) { "dev" } else { "release" }
}

/// The CPU the benchmark ran on, as Linux's `/proc/cpuinfo` names it (first processor), so that
/// figures from different machines are told apart: a cloud VM often reports only a family
/// ("AMD EPYC"), so the vendor's family, model and stepping numbers and the per-core L2 size
/// (`cache size`) are kept, with the widest vector extension detected at run time.
#[derive(Clone, Debug, serde::Serialize)]
pub struct CpuInfo {
    pub model_name: String,
    pub vendor: String,
    pub family: Option<u32>,
    pub model: Option<u32>,
    pub stepping: Option<u32>,
    pub cache: String,
    pub logical_cpus: usize,
    /// "avx512f", "avx2", "sse2" or "" (not x86-64).
    pub widest_simd: &'static str,
}

impl CpuInfo {
    /// This machine's description: its `/proc/cpuinfo` (fields left empty where that file is
    /// missing), its CPU count and the widest SIMD it has.
    pub fn detect() -> Self {
        #[cfg(target_arch = "x86_64")]
        let widest_simd = if std::arch::is_x86_feature_detected!("avx512f") {
            "avx512f"
        } else if std::arch::is_x86_feature_detected!("avx2") {
            "avx2"
        } else {
            "sse2"
        };
        #[cfg(not(target_arch = "x86_64"))]
        let widest_simd = "";
        let logical_cpus = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
        Self::parse(&std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default(), logical_cpus, widest_simd)
    }

    /// The description from the text of a `/proc/cpuinfo` (its first processor's block), with
    /// the CPU count and SIMD level detected elsewhere.
    pub fn parse(cpuinfo: &str, logical_cpus: usize, widest_simd: &'static str) -> Self {
        let first = cpuinfo.split("\n\n").next().unwrap_or("");
        let field = |key: &str| {
            first.lines().find_map(|l| {
                let (k, v) = l.split_once(':')?;
                (k.trim() == key).then(|| v.trim().to_string())
            })
        };
        let number = |key: &str| field(key).and_then(|v| v.parse().ok());
        CpuInfo {
            model_name: field("model name").unwrap_or_else(|| "unknown".into()),
            vendor: field("vendor_id").unwrap_or_default(),
            family: number("cpu family"),
            model: number("model"),
            stepping: number("stepping"),
            cache: field("cache size").unwrap_or_default(),
            logical_cpus,
            widest_simd,
        }
    }

    /// One line: `AMD EPYC (AuthenticAMD family 25 model 17 stepping 1, cache 1024 KB, 2 CPUs, avx512f)`.
    pub fn summary(&self) -> String {
        let num = |n: Option<u32>| n.map_or("?".to_string(), |n| n.to_string());
        format!(
            "{} ({} family {} model {} stepping {}, cache {}, {} CPUs, {})",
            self.model_name,
            if self.vendor.is_empty() { "unknown vendor" } else { &self.vendor },
            num(self.family),
            num(self.model),
            num(self.stepping),
            if self.cache.is_empty() { "?" } else { &self.cache },
            self.logical_cpus,
            if self.widest_simd.is_empty() { "no x86 SIMD" } else { self.widest_simd }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cpu_is_read_from_the_first_processor_of_proc_cpuinfo() {
        let text = "processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 25\nmodel\t\t: 17\nmodel name\t: AMD EPYC\n\
                    stepping\t: 1\ncache size\t: 1024 KB\nflags\t\t: fpu avx2\n\nprocessor\t: 1\nvendor_id\t: Other\nmodel\t\t: 99\n";
        let cpu = CpuInfo::parse(text, 2, "avx512f");
        assert_eq!((cpu.model_name.as_str(), cpu.vendor.as_str()), ("AMD EPYC", "AuthenticAMD"));
        assert_eq!((cpu.family, cpu.model, cpu.stepping), (Some(25), Some(17), Some(1)));
        assert_eq!(cpu.cache, "1024 KB");
        assert_eq!(cpu.summary(), "AMD EPYC (AuthenticAMD family 25 model 17 stepping 1, cache 1024 KB, 2 CPUs, avx512f)");
        // No /proc/cpuinfo (another OS): named as unknown, not an error.
        let none = CpuInfo::parse("", 1, "");
        assert_eq!((none.model_name.as_str(), none.family), ("unknown", None));
        assert_eq!(none.summary(), "unknown (unknown vendor family ? model ? stepping ?, cache ?, 1 CPUs, no x86 SIMD)");
    }
}
