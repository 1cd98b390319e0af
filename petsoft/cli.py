"""The `petsoft` console command."""


def main(argv=None) -> int:
    raise SystemExit("petsoft: not yet implemented")
