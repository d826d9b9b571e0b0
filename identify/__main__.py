from .cli.app import program

program()
