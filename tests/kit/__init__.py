"""The lab kit the tests and the benchmarks share: plain modules, no fixtures.

Lab starters, waits, the Playwright page helpers, the viewer's protocol client,
the worlds the engine's benchmarks measure. bench/ imports from tests/ only this
package, and this package imports neither bench/ nor a test module
(tests/unit/test_import_contracts.py checks both); fixtures stay in conftest.py
files and build on it.
"""
