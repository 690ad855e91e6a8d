"""Study files (TOML) shipped with the package: the paper's reproduction and design studies."""
