"""Examples of kilonet programs (not installed with kilonet; run them from the repository root)."""
