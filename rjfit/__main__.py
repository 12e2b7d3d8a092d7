from rjfit.cli import main

main(prog_name="rjfit")
