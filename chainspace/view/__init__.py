"""Looking at results: the meshcat viewer and matplotlib plots."""
