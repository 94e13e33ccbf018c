//! Plots (SVG through plotters): residuals against each quantity, and the model history.
