//! Pure ARCOS/P2OS codec for Pioneer robots (bytes in, typed values out, no I/O).
