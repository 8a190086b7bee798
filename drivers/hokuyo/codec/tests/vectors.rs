//! Decodes every real capture in `tests/vectors/` (SCIP 2.0 exchanges,
//! byte-exact) and rejects the damaged one.
//!
//! Expected numbers were worked out by hand from the capture text and checked
//! with an independent decoder (strip checksums, join, 3 chars per value).

use smokenav_hokuyo_codec::{
    Command, DecodeError, FrameSplitter, Geometry, ModelFamily, Reading, SensorSpec, SensorState,
    Status, VersionInfo, decode_capture, parse_param_line, parse_reply,
};

fn vector(name: &str) -> Vec<u8> {
    let path = format!("{}/tests/vectors/{name}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

fn frames(bytes: &[u8]) -> Vec<Vec<u8>> {
    let mut s = FrameSplitter::default();
    let mut out = Vec::new();
    s.feed(bytes, |f| out.push(f.to_vec()));
    assert!(s.pending().is_empty(), "capture ends inside a reply");
    out
}

#[test]
fn wiki_vv_pp_ii_capture_decodes_all_three_replies() {
    let f = frames(&vector("A_wiki_vv_pp_ii.txt"));
    assert_eq!(f.len(), 3);

    let vv = VersionInfo::from_reply(&parse_reply(&f[0]).unwrap()).unwrap();
    assert_eq!(vv.vendor, "Hokuyo Automatic Co.,Ltd.");
    assert_eq!(vv.product, "SOKUIKI Sensor URG-04LX");
    assert_eq!(vv.firmware, "3.1.00(18/Jan./2007)");
    assert_eq!(vv.protocol, "SCIP 2.0");
    assert_eq!(vv.serial, "H0614967");

    let pp = SensorSpec::from_reply(&parse_reply(&f[1]).unwrap()).unwrap();
    assert_eq!(pp.model, "URG-04LX(Hokuyo Automatic Co.,Ltd.)");
    assert_eq!(
        pp.geometry,
        Geometry {
            dmin_mm: 20,
            dmax_mm: 5600,
            ares: 1024,
            amin: 44,
            amax: 725,
            afrt: 384,
            scan_rpm: 600
        }
    );
    assert_eq!(pp.family(), ModelFamily::Urg04lx);
    assert!(!pp.family().supports_intensity());

    let ii = SensorState::from_reply(&parse_reply(&f[2]).unwrap()).unwrap();
    assert_eq!(ii.laser, "OFF");
    assert_eq!(ii.scan_speed, "Initial(600[rpm])<-Default setting by user");
    assert_eq!(ii.measure_mode, "IDLE");
    assert_eq!(ii.bit_rate, "19200[bps]<-Default setting by user");
    assert_eq!(ii.time, "081615");
    assert_eq!(ii.stat, "Sensor works well.");
    assert!(ii.is_healthy());
}

#[test]
fn ug01_gd_full_scan_decodes_682_ranges_and_codes_0_6_7() {
    let f = frames(&vector("D_ug01_gd_full.txt"));
    assert_eq!(f.len(), 1);
    let reply = parse_reply(&f[0]).unwrap();
    assert_eq!(reply.echo.command, Command::Gd);
    assert_eq!(reply.status, Status::OK);
    let mut ranges = [0u32; 1081];
    let h = reply.decode_scan(&mut ranges, &mut []).unwrap();
    // `ZR3h7`: Z=42, R=34, 3=3, h=56 → 42·2^18 + 34·2^12 + 3·2^6 + 56 = 11 149 560 ms.
    assert_eq!(h.timestamp, 11_149_560);
    assert_eq!(
        (h.echo.range.start, h.echo.range.end, h.echo.range.cluster),
        (44, 725, 1)
    );
    assert_eq!(h.count, 682);
    let r = &ranges[..682];
    // Line 4 starts `006 006 006 11N 006 007 …`: `11N` = 1·4096 + 1·64 + 30 = 4190 mm.
    assert_eq!(&r[..8], &[6, 6, 6, 4190, 6, 7, 6, 6]);
    // `0fa` = 54·64 + 49 = 3505 and `0dG` = 52·64 + 23 = 3351.
    assert_eq!(&r[18..21], &[3505, 3351, 3505]);
    // Value 21 is split: `0` ends line 4, `fa` starts line 5.
    assert_eq!(r[21], 3505);
    assert_eq!(r[42], 961);

    let g = Geometry {
        dmin_mm: 20,
        dmax_mm: 5600,
        ares: 1024,
        amin: 44,
        amax: 725,
        afrt: 384,
        scan_rpm: 600,
    };
    let count_code = |c| {
        r.iter()
            .filter(|&&v| g.classify(v) == Reading::Code(c))
            .count()
    };
    assert_eq!((count_code(0), count_code(6), count_code(7)), (53, 24, 8));
    let ranges_mm: Vec<u32> = r
        .iter()
        .filter_map(|&v| match g.classify(v) {
            Reading::Range(mm) => Some(mm),
            _ => None,
        })
        .collect();
    assert_eq!(ranges_mm.len(), 597);
    assert_eq!(ranges_mm.iter().min(), Some(&90));
    assert_eq!(ranges_mm.iter().max(), Some(&5461));
    assert_eq!(
        ranges_mm.iter().map(|&v| u64::from(v)).sum::<u64>(),
        383_152
    );
    assert_eq!(&r[672..], &[0, 6, 0, 6, 6, 6, 0, 0, 0, 0]);
}

#[test]
fn urgstamped_param_values_containing_semicolons_parse_from_the_right() {
    let bytes = vector("H_urgstamped.txt");
    let lines: Vec<&[u8]> = bytes
        .split(|&b| b == b'\n')
        .filter(|l| !l.is_empty())
        .collect();
    assert_eq!(lines.len(), 2);
    let prot = parse_param_line(lines[0], 1).unwrap();
    assert_eq!((prot.key, prot.value), (&b"PROT"[..], &b"SCIP 2.0"[..]));
    let time = parse_param_line(lines[1], 2).unwrap();
    assert_eq!((time.key, time.value), (&b"TIME"[..], &b"j;o["[..]));
}

#[test]
fn utm30lx_ew_pp_gives_its_own_geometry() {
    let f = frames(&vector("I_utm30lxew_pp.txt"));
    let pp = SensorSpec::from_reply(&parse_reply(&f[0]).unwrap()).unwrap();
    assert_eq!(pp.model, "UTM-30LX-EW");
    assert_eq!(
        pp.geometry,
        Geometry {
            dmin_mm: 23,
            dmax_mm: 60_000,
            ares: 1440,
            amin: 0,
            amax: 1080,
            afrt: 540,
            scan_rpm: 2400
        }
    );
    assert_eq!(pp.geometry.step_count(), 1081);
    assert!((pp.geometry.scan_period_s() - 0.025).abs() < 1e-12);
    assert!(pp.family().supports_intensity());
}

#[test]
fn spec_pp_with_ocr_damaged_checksums_is_rejected() {
    let f = frames(&vector("C_spec_pp.txt"));
    let reply = parse_reply(&f[0]).unwrap();
    let results: Vec<_> = reply.params().collect();
    // MODL (line 3) has `;b` where `Co., Ltd.` needs `n`; ARES (line 6) `;/` where `\` is right.
    assert_eq!(
        results[0],
        Err(DecodeError::Checksum {
            line: 3,
            expected: b'n',
            found: b'b'
        })
    );
    assert_eq!(
        results[3],
        Err(DecodeError::Checksum {
            line: 6,
            expected: b'\\',
            found: b'/'
        })
    );
    assert_eq!(results.iter().filter(|r| r.is_err()).count(), 2);
    assert!(SensorSpec::from_reply(&reply).is_err());
}

#[test]
fn capture_json_keeps_error_codes_apart_from_ranges() {
    let out = decode_capture(&vector("D_ug01_gd_full.txt"), &Default::default());
    assert_eq!(out.len(), 1);
    let v: serde_json::Value = serde_json::from_str(&out[0].to_json_line()).unwrap();
    assert_eq!(v["command"], "GD");
    assert_eq!(v["status"], "00");
    assert_eq!(v["scan"]["timestamp_ms"], 11_149_560);
    let ranges = v["scan"]["ranges_m"].as_array().unwrap();
    assert_eq!(ranges.len(), 682);
    assert!(ranges[0].is_null());
    assert_eq!(ranges[3], 4.19);
    let errors = v["scan"]["errors"].as_array().unwrap();
    assert_eq!(errors.len(), 53 + 24 + 8);
    assert_eq!(errors[0]["step"], 44);
    assert_eq!(errors[0]["code"], 6);
}

#[test]
fn capture_json_uses_dmin_from_a_pp_reply_and_flags_damage() {
    let mut bytes = vector("A_wiki_vv_pp_ii.txt");
    bytes.extend(vector("C_spec_pp.txt"));
    bytes.extend(vector("D_ug01_gd_full.txt"));
    let out = decode_capture(&bytes, &Default::default());
    assert_eq!(out.len(), 5);
    assert_eq!(
        out[0].params.as_ref().unwrap().0[0],
        ("VEND".to_string(), "Hokuyo Automatic Co.,Ltd.".to_string())
    );
    assert!(out[3].error.as_ref().unwrap().contains("line 3: checksum"));
    let scan = out[4].scan.as_ref().unwrap();
    assert_eq!(scan.dmin_mm, 20);
    // Angle of step 44 from the capture's PP: (44 − 384)·2π/1024.
    assert!((scan.angle_min_rad.unwrap() + 2.086_213_871_3).abs() < 1e-9);
}
