//! Synthetic test cases (filled by the registration work).
