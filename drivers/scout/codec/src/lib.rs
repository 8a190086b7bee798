//! Pure codec for the Nomadic direct serial protocol of the Nomad Scout (bytes in, typed values out, no I/O).
