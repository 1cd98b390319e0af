"""The ``petsoft`` console command."""
