from rigcal.cli import main

main()
