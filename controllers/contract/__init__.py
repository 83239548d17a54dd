"""The safety-filter plug-in contract (docs/safety-filter.md): what a loop gives a filter and gets back, what a plug-in
declares it can do, its diagnostics, the built-in filters' declared parameter bounds and per-run figures. Imports the
rooms below it (core, model, energy).
"""
