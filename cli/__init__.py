"""The ``oprecon`` command-line application (click)."""
