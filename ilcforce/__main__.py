from ilcforce._entry import main

main()
