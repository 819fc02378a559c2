import sys

from .cli import main

# Guarded so that importing the package's modules (mkdocstrings' inspection does) runs no CLI.
if __name__ == "__main__":
    sys.exit(main())
