"""The lab's processes: one module (or package) per process, each with a ``main()``."""
