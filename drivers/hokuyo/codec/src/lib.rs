//! Pure SCIP 2.0 codec for Hokuyo laser scanners (bytes in, typed values out, no I/O).
